"""Recordings: the CSV contract of docs/architecture.md (`csvfile`) and the daemon's crash-safe segment files
(`format`, written by `writer`, read back by `reader`)."""
