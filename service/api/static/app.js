// Demo page: sends the pair to the service and shows disparity, confidence, validity, depth and the point
// cloud. One Compute = POST /disparity (npy + validity + confidence: multipart/mixed), and with a camera
// (focal length and baseline, or a calibration file) also POST /depth (npy) and POST /pointcloud (PLY),
// all with the same options; the page paints the maps itself.
"use strict";

import { GREY, autoRange, drawScale, paint } from "./colormap.js";
import { parseMultipart, parseNpy, parsePly } from "./formats.js";
import { CloudViewer } from "./viewer.js";

// Validity codes of the matcher (docs/architecture.md) and how the page paints them.
const VALIDITY = {
  0: ["valid", [26, 152, 80]],
  1: ["occluded", [253, 174, 97]],
  2: ["mismatch", [215, 48, 39]],
  3: ["no data", [0, 0, 0]],
  5: ["filled occlusion", [254, 224, 139]],
  6: ["filled mismatch", [244, 109, 67]],
};
// The sample pair's calibration is not published: these are illustrative values, not its rig's.
const SAMPLE = { maxDisparity: "32", focalPx: "300", baselineM: "0.05" };
// Downloads: the answer the page holds (npy, PLY), or a new request in another format.
const FILES = {
  "disparity-png16": { route: "/disparity", format: "png16", name: "disparity.png" },
  "disparity-npy": { held: "disparityNpy", name: "disparity.npy" },
  "disparity-pfm": { route: "/disparity", format: "pfm", name: "disparity.pfm" },
  "depth-png16": { route: "/depth", format: "png16", name: "depth.png" },
  "depth-npy": { held: "depthNpy", name: "depth.npy" },
  "depth-pfm": { route: "/depth", format: "pfm", name: "depth.pfm" },
  "pointcloud-ply": { held: "ply", name: "pointcloud.ply" },
};

const $ = (id) => document.getElementById(id);
let samplePair = null; // {left: Blob, right: Blob} once "Use the sample pair" was pressed
let shown = null; // what the results section shows, and the request that made it
let viewer = null;

function setStatus(text, isError = false) {
  $("status").textContent = text;
  $("status").className = isError ? "error" : "";
}

async function loadModelInfo() {
  try {
    const model = await (await fetch("/v1/model")).json();
    $("model-name").textContent = `${model.name} (default max disparity ${model.disparity.default_max})`;
  } catch (error) {
    $("model-name").textContent = "unavailable";
  }
  for (;;) { // until the model is warm: requests before that are answered 503
    const ready = await fetch("/readyz").then((r) => r.ok, () => false);
    $("readiness").textContent = ready ? "ready" : "warming up";
    if (ready) return;
    await new Promise((resolve) => setTimeout(resolve, 1000));
  }
}

async function useSamplePair() {
  const [left, right] = await Promise.all(
    ["/static/sample-left.png", "/static/sample-right.png"].map(async (url) => (await fetch(url)).blob()));
  samplePair = { left, right };
  $("left").value = "";
  $("right").value = "";
  $("max-disparity").value = SAMPLE.maxDisparity;
  $("focal-px").value = SAMPLE.focalPx;
  $("baseline-m").value = SAMPLE.baselineM;
  $("pair-source").textContent = "sample pair selected (225 x 187, disparities up to 28)";
  $("camera-hint").textContent = "Sample pair: illustrative focal length and baseline, not its rig's.";
}

function chosenPair() {
  const left = $("left").files[0];
  const right = $("right").files[0];
  if (left && right) return { left, right };
  if (samplePair && !left && !right) return samplePair;
  return null;
}

// What one Compute asks: `match` goes to every route; with a calibration file, `calib` (the file and its
// options) too, so that a raw rig is rectified alike everywhere; `camera` (focal length, baseline, or the
// calibration file; max depth, measured only) to /depth and /pointcloud. camera is null: disparity only.
function requestOptions() {
  const match = new URLSearchParams();
  for (const [id, name] of [["max-disparity", "max_disparity"], ["min-disparity", "min_disparity"]]) {
    if ($(id).value.trim()) match.set(name, $(id).value.trim());
  }
  for (const [id, name] of [["lr-check", "lr_check"], ["fill", "fill"], ["subpixel", "subpixel"]]) {
    match.set(name, $(id).checked ? "true" : "false");
  }
  const file = $("calib").files[0] || null;
  const calib = new URLSearchParams();
  if (file && $("calib-units").value !== "m") calib.set("calib_units", $("calib-units").value);
  if (file && $("calib-rectified").checked) calib.set("calib_rectified", "true");
  const camera = new URLSearchParams(calib);
  const [focal, baseline] = [$("focal-px").value.trim(), $("baseline-m").value.trim()];
  if (!file && Boolean(focal) !== Boolean(baseline)) {
    throw new Error("give both the focal length and the baseline (or neither, for disparity only)");
  }
  if (!file && focal) {
    camera.set("focal_px", focal);
    camera.set("baseline_m", baseline);
    for (const name of ["cx", "cy"]) if ($(name).value.trim()) camera.set(name, $(name).value.trim());
  }
  camera.set("diagnostics", "false"); // the disparity answer already says what is wrong with the pair
  if ($("max-depth").value.trim()) camera.set("max_depth", $("max-depth").value.trim());
  if ($("drop-filled").checked) camera.set("drop_filled", "true");
  return { match, file, calib, camera: file || focal ? camera : null };
}

// POST `route` with the pair (and the calibration file, if any) and the union of `queries`.
async function post(route, request, ...queries) {
  const { pair, file } = request;
  const body = new FormData();
  body.append("left", pair.left, pair.left.name || "left.png");
  body.append("right", pair.right, pair.right.name || "right.png");
  if (file) body.append("calib", file, file.name);
  const query = new URLSearchParams(queries.flatMap((q) => [...q.entries()]));
  const started = performance.now();
  const response = await fetch(`${route}?${query}`, { method: "POST", body });
  if (!response.ok) {
    const problem = await response.json().catch(() => ({ detail: response.statusText }));
    throw new Error(`${response.status}: ${problem.detail}`);
  }
  return { response, body: await response.arrayBuffer(), ms: performance.now() - started };
}

async function decodeCodes(blob) { // the validity PNG: grey, R = G = B = the code
  const image = await createImageBitmap(blob);
  const canvas = new OffscreenCanvas(image.width, image.height);
  const context = canvas.getContext("2d", { willReadFrequently: true });
  context.drawImage(image, 0, 0);
  const rgba = context.getImageData(0, 0, image.width, image.height).data;
  const codes = new Uint8Array(image.width * image.height);
  for (let i = 0; i < codes.length; i++) codes[i] = rgba[4 * i];
  return codes;
}

async function confidenceOf(blob) { // npy float32, or 8-bit PNG = confidence x 255
  const bytes = await blob.arrayBuffer();
  if (new Uint8Array(bytes)[0] === 0x93) return parseNpy(bytes).data;
  const codes = await decodeCodes(blob);
  return Float32Array.from(codes, (value) => value / 255);
}

async function compute(event) {
  event.preventDefault();
  clearResults();
  const pair = chosenPair();
  if (!pair) {
    setStatus("choose a left and a right image, or the sample pair", true);
    return;
  }
  $("compute").disabled = true;
  try {
    const request = { pair, ...requestOptions() };
    const { match, calib, camera } = request;
    setStatus("computing the disparity…");
    const maps = new URLSearchParams({ format: "npy", validity: "true", confidence: "true" });
    const answer = await post("/disparity", request, match, calib, maps);
    const parts = parseMultipart(answer.body, answer.response.headers.get("content-type"));
    const disparityNpy = parts.disparity;
    const disparity = parseNpy(await disparityNpy.arrayBuffer());
    const result = {
      request, disparity, disparityNpy, validity: await decodeCodes(parts.validity),
      confidence: parts.confidence ? await confidenceOf(parts.confidence) : null,
      timings: [["", answer]], requestId: answer.response.headers.get("x-request-id"),
      warnings: pairWarnings(answer.response.headers.get("x-adsm-warning")),
    };
    if (camera) {
      setStatus("computing the depth…");
      const npyFormat = new URLSearchParams({ format: "npy" });
      const depthAnswer = await post("/depth", request, match, camera, npyFormat);
      result.calibration = calibrationOf(depthAnswer.response.headers.get("x-adsm-calibration"));
      result.depthNpy = new Blob([depthAnswer.body], { type: "application/x-npy" });
      result.depth = parseNpy(depthAnswer.body).data;
      setStatus("computing the point cloud…");
      const cloudAnswer = await post("/pointcloud", request, match, camera);
      result.ply = new Blob([cloudAnswer.body], { type: "application/x-ply" });
      result.cloud = parsePly(cloudAnswer.body);
      result.timings.push(["depth request", depthAnswer], ["point cloud request", cloudAnswer]);
    }
    shown = result;
    $("left-preview").src = URL.createObjectURL(pair.left);
    showResults();
    const points = result.cloud ? `, ${result.cloud.count} points` : "";
    setStatus(`done: ${disparity.width} x ${disparity.height}${points}`);
  } catch (error) {
    clearResults(); // no answer from an earlier pair stays under the error
    setStatus(error.message, true);
  } finally {
    $("compute").disabled = false;
  }
}

// The X-ADSM-Warning headers (fetch joins repeated ones with ", "): one "kind: sentence" each.
function pairWarnings(header) {
  return header ? header.split(/,\s*(?=(?:swapped|unrectified|few-valid): )/) : [];
}

// X-ADSM-Calibration: "focal_px=...; baseline_m=...; ...; source=\"calib.txt (Middlebury)\"".
function calibrationOf(header) {
  const fields = {};
  for (const [, key, value] of (header || "").matchAll(/(\w+)=("[^"]*"|[^;]*)/g)) {
    fields[key] = value.replace(/^"|"$/g, "");
  }
  return fields;
}

function clearResults() {
  shown = null;
  $("results").hidden = true;
  $("warnings").hidden = true;
  $("warnings").replaceChildren();
  const preview = $("left-preview");
  if (preview.src) URL.revokeObjectURL(preview.src);
  preview.removeAttribute("src");
  for (const id of ["disparity", "confidence", "validity", "depth"]) $(id).width = $(id).height = 0;
  $("validity-legend").replaceChildren();
  $("timings").tBodies[0].replaceChildren();
  $("request-id").textContent = "";
  $("readout").textContent = "Point at a map to read its values.";
  if (viewer) viewer.clear();
}

function showResults() {
  const { disparity, cloud, confidence } = shown;
  $("results").hidden = false;
  $("confidence-figure").hidden = !confidence;
  $("depth-figure").hidden = !shown.depth;
  $("cloud-figure").hidden = !cloud;
  for (const element of document.querySelectorAll("#downloads .metric")) element.hidden = !shown.depth;
  $("warnings").replaceChildren(...shown.warnings.map((warning) => {
    const item = document.createElement("li");
    item.textContent = warning;
    return item;
  }));
  $("warnings").hidden = !shown.warnings.length;
  const calibration = shown.calibration;
  $("calibration-read").hidden = !calibration;
  if (calibration) {
    const from = calibration.source ? ` from ${calibration.source}` : "";
    const rectified = calibration.rectified === "true" ? "; the pair was rectified first" : "";
    $("calibration-read").textContent = `Camera${from}: focal length ${calibration.focal_px} px, baseline ` +
      `${calibration.baseline_m} m, principal point (${calibration.cx}, ${calibration.cy}) px, ` +
      `doffs ${calibration.doffs} px${rectified}.`;
  }
  drawValidity(shown.validity, disparity.width, disparity.height);
  paintMaps();
  showTimings();
  if (cloud) {
    $("point-count").textContent = cloud.count.toLocaleString("en");
    const focal = Number(shown.calibration.focal_px);
    // Points as large as an image pixel looks in the first view, so that it shows no gaps.
    const size = Math.min(8, Math.max(1, Math.round($("cloud").clientHeight / disparity.height)));
    $("point-size").value = String(size);
    viewer.setPointSize(size);
    viewer.show(cloud, { fovY: 2 * Math.atan(disparity.height / (2 * focal)) });
    $("webgl-missing").hidden = viewer.available;
  }
}

// Paints disparity, confidence and depth with the chosen colour range (no new request).
function paintMaps() {
  if (!shown) return;
  const { width, height, data } = shown.disparity;
  const fixed = $("range-fixed").checked;
  const range = (values, lowId, highId) => {
    const auto = autoRange(values);
    if (!fixed) {
      $(lowId).placeholder = auto[0].toFixed(2);
      $(highId).placeholder = auto[1].toFixed(2);
      return auto;
    }
    const [low, high] = [Number($(lowId).value || auto[0]), Number($(highId).value || auto[1])];
    return high > low ? [low, high] : auto;
  };
  const [low, high] = range(data, "disparity-low", "disparity-high");
  paint($("disparity"), data, width, height, { low, high });
  drawScale($("disparity-scale"), { low, high, unit: "px" });
  if (shown.confidence) {
    paint($("confidence"), shown.confidence, width, height, { low: 0, high: 1, lut: GREY });
    drawScale($("confidence-scale"), { low: 0, high: 1, unit: "", lut: GREY, digits: 2 });
  }
  if (shown.depth) {
    const [near, far] = range(shown.depth, "depth-low", "depth-high");
    paint($("depth"), shown.depth, width, height, { low: near, high: far, reversed: true });
    drawScale($("depth-scale"), { low: near, high: far, unit: "m", reversed: true, digits: 2 });
  }
}

function drawValidity(codes, width, height) {
  const canvas = $("validity");
  canvas.width = width;
  canvas.height = height;
  const context = canvas.getContext("2d");
  const pixels = context.createImageData(width, height);
  const counts = {};
  codes.forEach((code, i) => {
    counts[code] = (counts[code] || 0) + 1;
    pixels.data.set([...(VALIDITY[code] || ["unknown", [128, 128, 128]])[1], 255], 4 * i);
  });
  context.putImageData(pixels, 0, 0);
  $("validity-legend").replaceChildren(...Object.entries(counts).map(([code, count]) => {
    const [label, [r, g, b]] = VALIDITY[code] || ["unknown", [128, 128, 128]];
    const item = document.createElement("li");
    const swatch = document.createElement("span");
    swatch.className = "swatch";
    swatch.style.background = `rgb(${r}, ${g}, ${b})`;
    item.append(swatch, `${label}: ${(100 * count / codes.length).toFixed(1)} %`);
    return item;
  }));
}

function showTimings() {
  const rows = [];
  for (const [label, { response, ms }] of shown.timings) {
    const stages = (response.headers.get("server-timing") || "").split(",").map((m) => m.trim()).filter(Boolean);
    for (const metric of stages) {
      const [name, ...params] = metric.split(";");
      const duration = params.map((p) => p.trim()).find((p) => p.startsWith("dur="));
      // the disparity request stage by stage; the others by their total
      if (!label || name === "total") {
        rows.push([label ? `${label}: ${name}` : name, duration ? Number(duration.slice(4)) : NaN]);
      }
    }
    rows.push([label ? `${label}: round trip (browser)` : "round trip (browser)", ms]);
  }
  $("timings").tBodies[0].replaceChildren(...rows.map(([name, ms]) => {
    const row = document.createElement("tr");
    for (const text of [name, Number.isFinite(ms) ? ms.toFixed(1) : "?"]) row.insertCell().textContent = text;
    return row;
  }));
  $("request-id").textContent = shown.requestId;
}

// The values under the pointer, for any of the maps.
function readout(event) {
  if (!shown) return;
  const { width, height, data } = shown.disparity;
  const box = event.target.getBoundingClientRect();
  const u = Math.min(width - 1, Math.floor((event.clientX - box.left) / box.width * width));
  const v = Math.min(height - 1, Math.floor((event.clientY - box.top) / box.height * height));
  const i = v * width + u;
  const words = [`u ${u}, v ${v}:`, `disparity ${Number.isFinite(data[i]) ? data[i].toFixed(2) + " px" : "none"}`];
  if (shown.depth) words.push(`depth ${Number.isFinite(shown.depth[i]) ? shown.depth[i].toFixed(3) + " m" : "none"}`);
  if (shown.confidence) words.push(`confidence ${shown.confidence[i].toFixed(2)}`);
  words.push((VALIDITY[shown.validity[i]] || ["unknown"])[0]);
  $("readout").textContent = words.join(" · ");
}

async function download(event) {
  const file = FILES[event.target.dataset.file];
  if (!shown || !file) return;
  try {
    let blob = shown[file.held];
    if (!blob) {
      setStatus(`computing ${file.name}…`);
      const { match, calib, camera } = shown.request;
      const format = new URLSearchParams({ format: file.format });
      const queries = [match, file.route === "/disparity" ? calib : camera, format];
      blob = new Blob([(await post(file.route, shown.request, ...queries)).body]);
    }
    const link = document.createElement("a");
    link.href = URL.createObjectURL(blob);
    link.download = file.name;
    link.click();
    setTimeout(() => URL.revokeObjectURL(link.href), 10000);
    setStatus(`saved ${file.name}`);
  } catch (error) {
    setStatus(`${file.name}: ${error.message}`, true);
  }
}

document.addEventListener("DOMContentLoaded", () => {
  viewer = new CloudViewer($("cloud"));
  $("use-sample").addEventListener("click", () => useSamplePair().catch((e) => setStatus(e.message, true)));
  const cameraHint = $("camera-hint").textContent;
  for (const id of ["left", "right"]) {
    $(id).addEventListener("change", () => {
      $("pair-source").textContent = "";
      $("camera-hint").textContent = cameraHint;
    });
  }
  const calibChosen = () => { // a calibration file replaces the numbers typed by hand
    const chosen = Boolean($("calib").files[0]);
    for (const id of ["focal-px", "baseline-m", "cx", "cy"]) $(id).disabled = chosen;
    $("clear-calib").hidden = !chosen;
  };
  $("calib").addEventListener("change", calibChosen);
  $("clear-calib").addEventListener("click", () => { $("calib").value = ""; calibChosen(); });
  $("pair-form").addEventListener("submit", compute);
  for (const id of ["range-auto", "range-fixed", "disparity-low", "disparity-high", "depth-low", "depth-high"]) {
    $(id).addEventListener("input", paintMaps);
  }
  $("range-fixed").addEventListener("change", () => { // start from the range the maps show now
    for (const id of ["disparity-low", "disparity-high", "depth-low", "depth-high"]) {
      if (!$(id).value) $(id).value = $(id).placeholder;
    }
  });
  for (const id of ["disparity", "confidence", "validity", "depth"]) $(id).addEventListener("mousemove", readout);
  $("downloads").addEventListener("click", (event) => { if (event.target.dataset.file) download(event); });
  $("reset-view").addEventListener("click", () => viewer.reset());
  $("point-size").addEventListener("input", () => viewer.setPointSize(Number($("point-size").value)));
  loadModelInfo();
});
