// The point cloud in 3D on a canvas: orthographic view, turning slowly, drag to turn, wheel to zoom;
// each point coloured by its σ (mm, the 1σ position uncertainty) on a viridis-like ramp.
"use strict";

const Cloud = (() => {
  const RAMP = [[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]];
  let yaw = 0.6, pitch = 0.35, zoom = 1, auto = true, dragging = null;

  function color(u) {
    u = Math.min(1, Math.max(0, u)) * (RAMP.length - 1);
    const i = Math.min(RAMP.length - 2, Math.floor(u)), f = u - i;
    const c = RAMP[i].map((v, k) => Math.round(v + (RAMP[i + 1][k] - v) * f));
    return `rgb(${c[0]},${c[1]},${c[2]})`;
  }

  function quantile(sorted, q) {
    return sorted.length ? sorted[Math.min(sorted.length - 1, Math.floor(q * sorted.length))] : 0;
  }

  function attach(canvas, redraw) {
    canvas.addEventListener("mousedown", (e) => { dragging = [e.clientX, e.clientY]; auto = false; });
    window.addEventListener("mouseup", () => { dragging = null; });
    window.addEventListener("mousemove", (e) => {
      if (!dragging) return;
      yaw += (e.clientX - dragging[0]) * 0.01;
      pitch = Math.max(-1.5, Math.min(1.5, pitch + (e.clientY - dragging[1]) * 0.01));
      dragging = [e.clientX, e.clientY];
      redraw();
    });
    canvas.addEventListener("wheel", (e) => {
      e.preventDefault();
      zoom = Math.max(0.2, Math.min(20, zoom * (e.deltaY < 0 ? 1.15 : 1 / 1.15)));
      redraw();
    }, { passive: false });
    canvas.addEventListener("dblclick", () => { auto = true; zoom = 1; redraw(); });
  }

  // pts: [[x, y, z, sigma_mm, flags], ...] (m); returns how many were drawn
  function draw(canvas, pts, dt) {
    if (auto) yaw += 0.25 * (dt || 0);
    const { ctx, w, h } = Plot.fit(canvas);
    ctx.clearRect(0, 0, w, h);
    ctx.fillStyle = "#fbfcfe";
    ctx.fillRect(0, 0, w, h);
    ctx.font = "11px system-ui, sans-serif";
    if (!pts.length) {
      ctx.fillStyle = "#8a94a6"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
      ctx.fillText("no points yet (tvsctl scan start)", w / 2, h / 2);
      return 0;
    }
    // centre and scale from robust bounds (a few stray points do not shrink the cloud)
    const lo = [], hi = [], mid = [];
    for (let k = 0; k < 3; k++) {
      const s = pts.map((p) => p[k]).sort((a, b) => a - b);
      lo.push(quantile(s, 0.01)); hi.push(quantile(s, 0.99)); mid.push((lo[k] + hi[k]) / 2);
    }
    const span = Math.max(hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2], 1e-6);
    const scale = (Math.min(w, h) * 0.7 * zoom) / span;
    const cy = Math.cos(yaw), sy = Math.sin(yaw), cp = Math.cos(pitch), sp = Math.sin(pitch);
    const proj = (x, y, z) => {
      // z up; turn about z (yaw), then tilt about the screen's horizontal (pitch)
      const dx = x - mid[0], dy = y - mid[1], dz = z - mid[2];
      const rx = cy * dx - sy * dy, ry = sy * dx + cy * dy;
      const up = cp * dz - sp * ry, depth = sp * dz + cp * ry;
      return [w / 2 + rx * scale, h / 2 - up * scale, depth];
    };
    // the robust bounding box and the axes through its centre
    const box = [];
    for (const i of [0, 1]) for (const j of [0, 1]) for (const k of [0, 1])
      box.push(proj(i ? hi[0] : lo[0], j ? hi[1] : lo[1], k ? hi[2] : lo[2]));
    ctx.strokeStyle = "#d5dae3"; ctx.lineWidth = 1;
    for (let a = 0; a < 8; a++) for (let b = a + 1; b < 8; b++) {
      const d = a ^ b;
      if (d === 1 || d === 2 || d === 4) {
        ctx.beginPath(); ctx.moveTo(box[a][0], box[a][1]); ctx.lineTo(box[b][0], box[b][1]); ctx.stroke();
      }
    }
    const half = span * 0.6;
    ctx.fillStyle = "#5d6778"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
    [["x", [half, 0, 0]], ["y", [0, half, 0]], ["z", [0, 0, half]]].forEach(([name, v]) => {
      const o = proj(mid[0], mid[1], mid[2]), e = proj(mid[0] + v[0], mid[1] + v[1], mid[2] + v[2]);
      ctx.strokeStyle = "#8a94a6";
      ctx.beginPath(); ctx.moveTo(o[0], o[1]); ctx.lineTo(e[0], e[1]); ctx.stroke();
      ctx.fillText(name, e[0] + (e[0] - o[0]) * 0.08, e[1] + (e[1] - o[1]) * 0.08);
    });
    // colour scale from the σ of the points shown
    const sig = pts.map((p) => p[3]).sort((a, b) => a - b);
    const smin = quantile(sig, 0.02), smax = Math.max(quantile(sig, 0.98), smin * 1.0001 + 1e-12);
    const order = pts.map((p) => proj(p[0], p[1], p[2]).concat([p[3]])).sort((a, b) => a[2] - b[2]);
    const r = Math.max(1.5, Math.min(3.5, 600 / Math.sqrt(pts.length + 1) / 10));
    for (const p of order) {
      ctx.fillStyle = color((p[3] - smin) / (smax - smin));
      ctx.beginPath(); ctx.arc(p[0], p[1], r, 0, 2 * Math.PI); ctx.fill();
    }
    colorbar(ctx, w, h, smin, smax);
    ctx.fillStyle = "#5d6778"; ctx.textAlign = "left"; ctx.textBaseline = "bottom";
    ctx.fillText(`box ${(span * 1e3).toPrecision(3)} mm · centre (${mid.map((v) => v.toFixed(3)).join(", ")}) m`, 6, h - 4);
    return pts.length;
  }

  function colorbar(ctx, w, h, smin, smax) {
    const x = w - 22, y0 = 18, y1 = h - 40;
    for (let y = y0; y <= y1; y++) {
      ctx.fillStyle = color(1 - (y - y0) / (y1 - y0));
      ctx.fillRect(x, y, 10, 1);
    }
    ctx.fillStyle = "#5d6778"; ctx.textAlign = "right"; ctx.textBaseline = "middle";
    ctx.fillText(`${smax.toPrecision(3)}`, x - 3, y0);
    ctx.fillText(`${smin.toPrecision(3)}`, x - 3, y1);
    ctx.textBaseline = "top";
    ctx.fillText("σ mm", w - 4, 3);
  }

  return { draw, attach };
})();
