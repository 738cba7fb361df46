// Demo page: sends the pair to POST /disparity?format=color&validity=true and shows the answer.
"use strict";

// Validity codes of the matcher (docs/architecture.md) and how the page paints them.
const VALIDITY = {
  0: ["valid", [26, 152, 80]],
  1: ["occluded", [253, 174, 97]],
  2: ["mismatch", [215, 48, 39]],
  3: ["no data", [0, 0, 0]],
  5: ["filled occlusion", [254, 224, 139]],
  6: ["filled mismatch", [244, 109, 67]],
};

const $ = (id) => document.getElementById(id);
let samplePair = null; // {left: Blob, right: Blob} once "Use the sample pair" was pressed

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
  const ready = await fetch("/readyz");
  $("readiness").textContent = ready.ok ? "ready" : "warming up";
}

async function useSamplePair() {
  const [left, right] = await Promise.all(
    ["/static/sample-left.png", "/static/sample-right.png"].map(async (url) => (await fetch(url)).blob()));
  samplePair = { left, right };
  $("left").value = "";
  $("right").value = "";
  $("max-disparity").value = "32";
  $("pair-source").textContent = "sample pair selected (225 x 187, disparities up to 28)";
}

function chosenPair() {
  const left = $("left").files[0];
  const right = $("right").files[0];
  if (left && right) return { left, right };
  if (samplePair && !left && !right) return samplePair;
  return null;
}

function queryString() {
  const params = new URLSearchParams({ format: "color", validity: "true" });
  const maxDisparity = $("max-disparity").value.trim();
  if (maxDisparity) params.set("max_disparity", maxDisparity);
  for (const [id, name] of [["lr-check", "lr_check"], ["fill", "fill"], ["subpixel", "subpixel"]]) {
    params.set(name, $(id).checked ? "true" : "false");
  }
  return params.toString();
}

// Splits a multipart/mixed body into {name: Blob}; each part names itself in Content-Disposition.
function parseMultipart(buffer, contentType) {
  const boundary = /boundary="?([^";]+)"?/.exec(contentType)[1];
  const bytes = new Uint8Array(buffer);
  const delimiter = new TextEncoder().encode(`--${boundary}`);
  const blankLine = new TextEncoder().encode("\r\n\r\n");
  const parts = {};
  let at = indexOf(bytes, delimiter, 0);
  while (at >= 0 && !(bytes[at + delimiter.length] === 45 && bytes[at + delimiter.length + 1] === 45)) {
    const headStart = at + delimiter.length + 2; // skip CRLF after the delimiter
    const headEnd = indexOf(bytes, blankLine, headStart);
    const head = new TextDecoder().decode(bytes.subarray(headStart, headEnd));
    const next = indexOf(bytes, delimiter, headEnd + 4);
    const name = /[;\s]name="([^"]+)"/.exec(head)[1];
    const type = (/content-type:\s*([^\r\n]+)/i.exec(head) || [null, "application/octet-stream"])[1];
    parts[name] = new Blob([bytes.subarray(headEnd + 4, next - 2)], { type }); // part ends with CRLF
    at = next;
  }
  return parts;
}

function indexOf(haystack, needle, from) {
  outer: for (let i = from; i <= haystack.length - needle.length; i++) {
    for (let j = 0; j < needle.length; j++) if (haystack[i + j] !== needle[j]) continue outer;
    return i;
  }
  return -1;
}

async function drawValidity(blob) {
  const image = await createImageBitmap(blob);
  const canvas = $("validity");
  canvas.width = image.width;
  canvas.height = image.height;
  const context = canvas.getContext("2d", { willReadFrequently: true });
  context.drawImage(image, 0, 0);
  const pixels = context.getImageData(0, 0, image.width, image.height);
  const counts = {};
  for (let i = 0; i < pixels.data.length; i += 4) {
    const code = pixels.data[i]; // grey PNG: R = G = B = the validity code
    counts[code] = (counts[code] || 0) + 1;
    const colour = (VALIDITY[code] || ["unknown", [128, 128, 128]])[1];
    pixels.data.set([...colour, 255], i);
  }
  context.putImageData(pixels, 0, 0);
  const total = image.width * image.height;
  $("validity-legend").replaceChildren(...Object.entries(counts).map(([code, count]) => {
    const [label, [r, g, b]] = VALIDITY[code] || ["unknown", [128, 128, 128]];
    const item = document.createElement("li");
    item.innerHTML = `<span class="swatch" style="background: rgb(${r}, ${g}, ${b})"></span>`;
    item.append(`${label}: ${(100 * count / total).toFixed(1)} %`);
    return item;
  }));
}

function showTimings(header, roundTripMs) {
  const rows = (header || "").split(",").map((metric) => metric.trim()).filter(Boolean).map((metric) => {
    const [name, ...params] = metric.split(";");
    const duration = params.map((p) => p.trim()).find((p) => p.startsWith("dur="));
    return [name, duration ? Number(duration.slice(4)).toFixed(1) : "?"];
  });
  rows.push(["round trip (browser)", roundTripMs.toFixed(1)]);
  $("timings").tBodies[0].replaceChildren(...rows.map(([name, ms]) => {
    const row = document.createElement("tr");
    for (const text of [name, ms]) row.insertCell().textContent = text;
    return row;
  }));
}

async function compute(event) {
  event.preventDefault();
  const pair = chosenPair();
  if (!pair) {
    setStatus("choose a left and a right image, or the sample pair", true);
    return;
  }
  const body = new FormData();
  body.append("left", pair.left, pair.left.name || "left.png");
  body.append("right", pair.right, pair.right.name || "right.png");
  $("compute").disabled = true;
  setStatus("computing…");
  const started = performance.now();
  try {
    const response = await fetch(`/disparity?${queryString()}`, { method: "POST", body });
    if (!response.ok) {
      const problem = await response.json().catch(() => ({ detail: response.statusText }));
      throw new Error(`${response.status}: ${problem.detail}`);
    }
    const parts = parseMultipart(await response.arrayBuffer(), response.headers.get("content-type"));
    const roundTrip = performance.now() - started;
    $("left-preview").src = URL.createObjectURL(pair.left);
    const disparityImage = $("disparity");
    const loaded = new Promise((resolve) => { disparityImage.onload = resolve; });
    disparityImage.src = URL.createObjectURL(parts.disparity);
    await Promise.all([loaded, drawValidity(parts.validity)]);
    showTimings(response.headers.get("server-timing"), roundTrip);
    $("request-id").textContent = response.headers.get("x-request-id");
    $("results").hidden = false;
    setStatus(`done: ${disparityImage.naturalWidth} x ${disparityImage.naturalHeight}`);
  } catch (error) {
    setStatus(error.message, true);
  } finally {
    $("compute").disabled = false;
  }
}

document.addEventListener("DOMContentLoaded", () => {
  $("use-sample").addEventListener("click", () => useSamplePair().catch((e) => setStatus(e.message, true)));
  for (const id of ["left", "right"]) $(id).addEventListener("change", () => { $("pair-source").textContent = ""; });
  $("pair-form").addEventListener("submit", compute);
  loadModelInfo();
});
