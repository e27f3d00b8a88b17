"""The daemon's live, read-only web view (config section `web:`, off by default).

`server.WebView` (aiohttp on the daemon's event loop: routes, the push, slow browsers),
`feed.LiveFeed` (the bounded series each browser reads from its cursor), `spectra.ImuWindow`
(both IMUs' Welch spectra), `floor.FloorProbe` (the machine's wake-up floor beside the loop),
`reports` (the doctor's reports in the data directory, served without a way out of it),
`http` (the page's files, headers, read-only answers, the origin check);
`static/` holds the page (plain JavaScript and canvas, no library).
"""
