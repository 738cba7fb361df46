// Colour maps of the demo page: Turbo for disparity (near = red) and depth (near = red), grey for
// confidence, each with a colour bar in the map's unit. Painted here rather than by the service's
// format=color so that a new colour range repaints at once without running the matcher again.
"use strict";

// R. Du's degree-5 polynomial fit of Turbo (Copyright 2019 Google LLC, Apache-2.0): coefficients of
// x^0 .. x^5 for red, green and blue, the same as service/io/colormap.py's (tests/e2e/test_demo_page.py
// compares the two 256-entry tables), so the page and format=color paint a value alike.
const TURBO_POLYNOMIAL = [
  [0.13572138, 4.6153926, -42.66032258, 132.13108234, -152.94239396, 59.28637943],
  [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604],
  [0.1066733, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973],
];

function table(entries, colour) {
  const rgb = new Uint8Array(3 * entries);
  for (let i = 0; i < entries; i++) rgb.set(colour(i / (entries - 1)), 3 * i);
  return rgb;
}

export const TURBO = table(256, (x) => TURBO_POLYNOMIAL.map((coefficients) => {
  const value = coefficients.reduce((sum, c, power) => sum + c * x ** power, 0);
  return Math.round(255 * Math.min(1, Math.max(0, value)));
}));
export const GREY = table(256, (x) => [0, 0, 0].map(() => Math.round(255 * x)));

// [low, high] of the finite values: their 1st and 99th percentiles, so that a few stray pixels (a far
// filled background at 100 m) do not squeeze every other colour into one end of the map.
export function autoRange(values) {
  const step = Math.max(1, Math.floor(values.length / 200000)); // a regular sample of big maps
  const finite = [];
  for (let i = 0; i < values.length; i += step) if (Number.isFinite(values[i])) finite.push(values[i]);
  if (!finite.length) return [0, 1];
  finite.sort((a, b) => a - b);
  const at = (q) => finite[Math.min(finite.length - 1, Math.round(q * (finite.length - 1)))];
  const [low, high] = [at(0.01), at(0.99)];
  return high > low ? [low, high] : [low, low + 1];
}

// Paints `values` (Float32Array, NaN = none: black) into `canvas`; values outside [low, high] take the
// end colours. `reversed` puts `low` at the red end (depth: near is red).
export function paint(canvas, values, width, height, { low, high, lut = TURBO, reversed = false }) {
  canvas.width = width;
  canvas.height = height;
  const context = canvas.getContext("2d");
  const image = context.createImageData(width, height);
  const last = lut.length / 3 - 1;
  const scale = last / (high - low);
  for (let i = 0; i < values.length; i++) {
    const value = values[i];
    let rgb = [0, 0, 0];
    if (Number.isFinite(value)) {
      let index = Math.round((value - low) * scale);
      index = Math.min(last, Math.max(0, reversed ? last - index : index));
      rgb = lut.subarray(3 * index, 3 * index + 3);
    }
    image.data.set(rgb, 4 * i);
    image.data[4 * i + 3] = 255;
  }
  context.putImageData(image, 0, 0);
}

// Draws a colour bar into `scale` (a .scale element holding a canvas and a .ticks row) for [low, high]
// in `unit`, five ticks from left (low) to right (high).
export function drawScale(scale, { low, high, unit, lut = TURBO, reversed = false, digits = 1 }) {
  const bar = scale.querySelector("canvas");
  const entries = lut.length / 3;
  bar.width = entries;
  bar.height = 1;
  const context = bar.getContext("2d");
  const image = context.createImageData(entries, 1);
  for (let i = 0; i < entries; i++) {
    const index = reversed ? entries - 1 - i : i;
    image.data.set([...lut.subarray(3 * index, 3 * index + 3), 255], 4 * i);
  }
  context.putImageData(image, 0, 0);
  scale.querySelector(".ticks").replaceChildren(...[0, 0.25, 0.5, 0.75, 1].map((f) => {
    const tick = document.createElement("span");
    tick.textContent = `${(low + f * (high - low)).toFixed(digits)}${f === 1 ? ` ${unit}` : ""}`;
    return tick;
  }));
}
