// A model-doctor report (report.md, tvsd.analysis.report) rendered as HTML. The Markdown it
// writes is a small subset: headings, paragraphs, pipe tables, images, **bold**, `code`, lists.
// Everything is built as DOM nodes with textContent: nothing in the file is taken as HTML.
"use strict";

function inline(text) {
  const frag = document.createDocumentFragment();
  const re = /(\*\*([^*]+)\*\*|`([^`]+)`|!\[([^\]]*)\]\(([^)\s]+)\))/g;
  let last = 0, m;
  while ((m = re.exec(text)) !== null) {
    if (m.index > last) frag.append(document.createTextNode(text.slice(last, m.index)));
    if (m[2] !== undefined) { const b = document.createElement("strong"); b.append(inline(m[2])); frag.append(b); }
    else if (m[3] !== undefined) { const c = document.createElement("code"); c.textContent = m[3]; frag.append(c); }
    else frag.append(image(m[4], m[5]));
    last = re.lastIndex;
  }
  if (last < text.length) frag.append(document.createTextNode(text.slice(last)));
  return frag;
}

let base = "";
function image(alt, src) {
  const img = document.createElement("img");
  img.alt = alt;
  // only files beside the report, through the server's checked route
  if (!/^[A-Za-z0-9._-]+(\/[A-Za-z0-9._-]+)*$/.test(src) || src.includes("..")) {
    img.title = `not shown: ${src}`;
    return img;
  }
  img.src = `reports/${base}${src}`;
  img.style.maxWidth = "100%";
  return img;
}

function render(md) {
  const out = document.createDocumentFragment();
  const lines = md.split("\n");
  for (let i = 0; i < lines.length;) {
    const line = lines[i];
    const h = /^(#{1,4})\s+(.*)$/.exec(line);
    if (h) { const e = document.createElement(`h${h[1].length}`); e.append(inline(h[2])); out.append(e); i++; continue; }
    if (line.startsWith("|")) {
      const table = document.createElement("table"); table.className = "kv";
      let first = true;
      for (; i < lines.length && lines[i].startsWith("|"); i++) {
        const cells = lines[i].replace(/^\||\|$/g, "").split("|").map((c) => c.trim());
        if (cells.every((c) => /^:?-+:?$/.test(c))) continue;
        const tr = document.createElement("tr");
        for (const c of cells) { const td = document.createElement(first ? "th" : "td"); td.append(inline(c)); tr.append(td); }
        table.append(tr);
        first = false;
      }
      out.append(table);
      continue;
    }
    if (/^\s*[-*]\s+/.test(line)) {
      const ul = document.createElement("ul");
      for (; i < lines.length && /^\s*[-*]\s+/.test(lines[i]); i++) {
        const li = document.createElement("li"); li.append(inline(lines[i].replace(/^\s*[-*]\s+/, ""))); ul.append(li);
      }
      out.append(ul);
      continue;
    }
    if (!line.trim()) { i++; continue; }
    const p = document.createElement("p");
    const para = [];
    for (; i < lines.length && lines[i].trim() && !/^(#|\||\s*[-*]\s)/.test(lines[i]); i++) para.push(lines[i]);
    p.append(inline(para.join(" ")));
    out.append(p);
  }
  return out;
}

(async () => {
  const path = new URLSearchParams(location.search).get("path") || "";
  document.getElementById("where").textContent = path;
  base = path.includes("/") ? path.slice(0, path.lastIndexOf("/") + 1).split("/").map(encodeURIComponent).join("/") : "";
  const art = document.getElementById("report");
  const res = await fetch(`reports/${path.split("/").map(encodeURIComponent).join("/")}`);
  if (!res.ok) { art.textContent = `${res.status}: ${await res.text()}`; return; }
  art.replaceChildren(render(await res.text()));
})();
