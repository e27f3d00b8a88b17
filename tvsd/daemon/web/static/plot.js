// Line plots on a canvas: linear or log y, dashed reference lines, labelled vertical markers.
"use strict";

const Plot = (() => {
  const PAD = { l: 56, r: 12, t: 10, b: 34 };

  function fit(canvas) {
    // Backing store at the device's pixel ratio, drawing in CSS pixels.
    const r = window.devicePixelRatio || 1;
    const w = canvas.clientWidth, h = canvas.clientHeight;
    if (canvas.width !== Math.round(w * r) || canvas.height !== Math.round(h * r)) {
      canvas.width = Math.round(w * r);
      canvas.height = Math.round(h * r);
    }
    const ctx = canvas.getContext("2d");
    ctx.setTransform(r, 0, 0, r, 0, 0);
    return { ctx, w, h };
  }

  function niceStep(span, n) {
    const raw = span / Math.max(1, n);
    const mag = Math.pow(10, Math.floor(Math.log10(raw)));
    const f = raw / mag;
    return (f < 1.5 ? 1 : f < 3 ? 2 : f < 7 ? 5 : 10) * mag;
  }

  function ticks(lo, hi, n) {
    const step = niceStep(hi - lo || 1, n);
    const out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) out.push(+v.toPrecision(12));
    return out;
  }

  function fmt(v) {
    const a = Math.abs(v);
    if (a === 0) return "0";
    if (a >= 1e4 || a < 1e-2) return v.toExponential(0);
    return +v.toPrecision(3) + "";
  }

  // opts: {series: [{x, y, color, label, dash, width}], hlines: [{y, color, label, dash}],
  //        vlines: [{x, color, label}], xmin, xmax, ymin, ymax, logy, xlabel, ylabel, empty}
  function draw(canvas, opts) {
    const { ctx, w, h } = fit(canvas);
    ctx.clearRect(0, 0, w, h);
    ctx.fillStyle = "#fff";
    ctx.fillRect(0, 0, w, h);
    const pw = w - PAD.l - PAD.r, ph = h - PAD.t - PAD.b;
    const tr = opts.logy ? (v) => (v > 0 ? Math.log10(v) : NaN) : (v) => v;
    let ys = [];
    for (const s of opts.series) for (const v of s.y) if (v !== null && isFinite(tr(v))) ys.push(tr(v));
    for (const l of opts.hlines || []) if (l.y !== null && isFinite(tr(l.y))) ys.push(tr(l.y));
    let ylo = opts.ymin !== undefined ? tr(opts.ymin) : Math.min(...ys);
    let yhi = opts.ymax !== undefined ? tr(opts.ymax) : Math.max(...ys);
    if (!isFinite(ylo) || !isFinite(yhi)) { ylo = 0; yhi = 1; }
    if (yhi - ylo < 1e-9) { const m = Math.abs(yhi) * 0.05 || 0.5; ylo -= m; yhi += m; }
    else if (opts.ymin === undefined) { const m = (yhi - ylo) * 0.06; ylo -= m; yhi += m; }
    const xlo = opts.xmin, xhi = opts.xmax;
    const X = (x) => PAD.l + ((x - xlo) / (xhi - xlo)) * pw;
    const Y = (y) => PAD.t + (1 - (tr(y) - ylo) / (yhi - ylo)) * ph;
    // grid and axes
    ctx.font = "11px system-ui, sans-serif";
    ctx.strokeStyle = "#e6e9ef";
    ctx.fillStyle = "#677285";
    ctx.lineWidth = 1;
    ctx.textAlign = "right";
    ctx.textBaseline = "middle";
    const yt = opts.logy ? ticks(Math.floor(ylo), Math.ceil(yhi), 4).filter((v) => Number.isInteger(v)) : ticks(ylo, yhi, 5);
    for (const t of yt) {
      const py = PAD.t + (1 - (t - ylo) / (yhi - ylo)) * ph;
      if (py < PAD.t - 1 || py > PAD.t + ph + 1) continue;
      ctx.beginPath(); ctx.moveTo(PAD.l, py); ctx.lineTo(PAD.l + pw, py); ctx.stroke();
      ctx.fillText(opts.logy ? fmt(Math.pow(10, t)) : fmt(t), PAD.l - 5, py);
    }
    ctx.textAlign = "center";
    ctx.textBaseline = "top";
    for (const t of ticks(xlo, xhi, Math.max(3, Math.floor(pw / 70)))) {
      const px = X(t);
      ctx.beginPath(); ctx.moveTo(px, PAD.t); ctx.lineTo(px, PAD.t + ph); ctx.stroke();
      ctx.fillText(fmt(t), px, PAD.t + ph + 4);
    }
    ctx.strokeStyle = "#99a3b3";
    ctx.strokeRect(PAD.l, PAD.t, pw, ph);
    ctx.fillText(opts.xlabel || "", PAD.l + pw / 2, h - 14);
    ctx.save();
    ctx.translate(12, PAD.t + ph / 2);
    ctx.rotate(-Math.PI / 2);
    ctx.fillText(opts.ylabel || "", 0, -6);
    ctx.restore();
    ctx.save();
    ctx.beginPath(); ctx.rect(PAD.l, PAD.t, pw, ph); ctx.clip();
    for (const v of opts.vlines || []) {
      if (v.x < xlo || v.x > xhi) continue;
      ctx.strokeStyle = v.color || "#b0b8c6";
      ctx.setLineDash([3, 3]);
      ctx.beginPath(); ctx.moveTo(X(v.x), PAD.t); ctx.lineTo(X(v.x), PAD.t + ph); ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = v.color || "#8a94a6";
      ctx.textAlign = "left";
      ctx.fillText(v.label || "", X(v.x) + 2, PAD.t + 2);
    }
    for (const l of opts.hlines || []) {
      if (l.y === null || !isFinite(tr(l.y))) continue;
      ctx.strokeStyle = l.color; ctx.lineWidth = 1.5;
      ctx.setLineDash(l.dash || [6, 4]);
      ctx.beginPath(); ctx.moveTo(PAD.l, Y(l.y)); ctx.lineTo(PAD.l + pw, Y(l.y)); ctx.stroke();
      ctx.setLineDash([]);
    }
    for (const s of opts.series) {
      ctx.strokeStyle = s.color; ctx.lineWidth = s.width || 1.5;
      ctx.setLineDash(s.dash || []);
      ctx.beginPath();
      let pen = false;
      for (let i = 0; i < s.x.length; i++) {
        const v = s.y[i];
        if (v === null || !isFinite(tr(v))) { pen = false; continue; }
        if (pen) ctx.lineTo(X(s.x[i]), Y(v)); else ctx.moveTo(X(s.x[i]), Y(v));
        pen = true;
      }
      ctx.stroke();
      ctx.setLineDash([]);
    }
    ctx.restore();
    legend(ctx, [...opts.series, ...(opts.hlines || [])].filter((s) => s.label), PAD.l + 8, PAD.t + 6);
    if (opts.empty) {
      ctx.fillStyle = "#8a94a6"; ctx.textAlign = "center"; ctx.textBaseline = "middle";
      ctx.font = "13px system-ui, sans-serif";
      ctx.fillText(opts.empty, PAD.l + pw / 2, PAD.t + ph / 2);
    }
  }

  function legend(ctx, items, x, y) {
    ctx.font = "11px system-ui, sans-serif";
    ctx.textAlign = "left"; ctx.textBaseline = "middle";
    let px = x;
    for (const it of items) {
      const wtext = ctx.measureText(it.label).width;
      ctx.fillStyle = "rgba(255,255,255,0.85)";
      ctx.fillRect(px - 2, y - 7, wtext + 28, 14);
      ctx.strokeStyle = it.color; ctx.lineWidth = 2; ctx.setLineDash(it.dash || []);
      ctx.beginPath(); ctx.moveTo(px, y); ctx.lineTo(px + 18, y); ctx.stroke();
      ctx.setLineDash([]);
      ctx.fillStyle = "#1d2430";
      ctx.fillText(it.label, px + 22, y);
      px += wtext + 36;
    }
  }

  return { draw, fit };
})();
