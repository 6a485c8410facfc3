// The error-against-run-time chart: held-out PSNR (dB, left axis), LPIPS and AVGE (right
// axis) against training seconds, one point per record, filling in as records arrive (an
// all-view final record after a curve over fewer views is left off the line, see add).

import uPlot from "uplot";

const COLOURS = { psnr: "#2563eb", lpips: "#dc2626", avge: "#059669" };

export function errorChart(container, { width = 640, height = 300 } = {}) {
  const data = [[], [], [], []]; // seconds, psnr, lpips, avge
  const records = [];
  const options = {
    width,
    height,
    title: "Held-out error against training time",
    scales: { x: { time: false }, db: { auto: true }, err: { auto: true } },
    axes: [
      { label: "training seconds", values: (u, ticks) => ticks.map((t) => `${+t.toFixed(1)}`) },
      { scale: "db", label: "PSNR (dB)", stroke: COLOURS.psnr },
      { scale: "err", label: "LPIPS / AVGE", side: 1, stroke: "#444", grid: { show: false } },
    ],
    series: [
      { label: "s", value: (u, v) => (v == null ? "–" : `${v.toFixed(1)} s`) },
      { label: "PSNR", scale: "db", stroke: COLOURS.psnr, width: 2, points: { size: 6 }, value: (u, v) => (v == null ? "–" : `${v.toFixed(2)} dB`) },
      { label: "LPIPS", scale: "err", stroke: COLOURS.lpips, width: 2, points: { size: 6 }, value: (u, v) => (v == null ? "–" : v.toFixed(3)) },
      { label: "AVGE", scale: "err", stroke: COLOURS.avge, width: 2, dash: [6, 4], points: { size: 6 }, value: (u, v) => (v == null ? "–" : v.toFixed(3)) },
    ],
    legend: { live: true },
    cursor: { drag: { x: false, y: false } },
  };
  const plot = new uPlot(options, data, container);
  container.dataset.points = "0";

  function add(record) {
    // Records arrive in order; a resumed run can repeat an iteration: keep the newest.
    const last = records[records.length - 1];
    if (last && record.elapsed_s < last.elapsed_s) {
      const i = records.findIndex((r) => r.elapsed_s >= record.elapsed_s);
      records.splice(i, records.length - i);
    }
    records.push(record);
    // Interim records score a fixed few held-out views and the final one all of them; the
    // trainer closes the curve with the few's figure at the same iteration just before it. The
    // final figure is the "Latest record" beside the chart, not a step on the line, which
    // would read as progress made in the last seconds.
    const line = records.filter((r, i) => {
      const prev = records[i - 1];
      return !(r.final && prev && !prev.final && prev.iteration === r.iteration && (prev.views ?? 0) < (r.views ?? 0));
    });
    data[0] = line.map((r) => r.elapsed_s);
    data[1] = line.map((r) => r.psnr ?? null);
    data[2] = line.map((r) => r.lpips ?? null);
    data[3] = line.map((r) => r.avge ?? null);
    plot.setData(data);
    container.dataset.points = String(records.length);
  }

  return {
    plot,
    records,
    add,
    resize(w, h) {
      plot.setSize({ width: w, height: h });
    },
    destroy() {
      plot.destroy();
    },
  };
}
