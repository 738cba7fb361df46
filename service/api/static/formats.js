// The service's answers, read in the browser: multipart/mixed (a part per map), npy float32 maps and
// binary little-endian PLY point clouds (docs/service.md, "Formats").
"use strict";

const encoder = new TextEncoder();

// {name: Blob} of a multipart/mixed body; each part names itself in Content-Disposition.
export function parseMultipart(buffer, contentType) {
  const boundary = /boundary="?([^";]+)"?/.exec(contentType || "");
  if (!boundary) throw new Error(`expected a multipart answer, got ${contentType}`);
  const bytes = new Uint8Array(buffer);
  const delimiter = encoder.encode(`--${boundary[1]}`);
  const blankLine = encoder.encode("\r\n\r\n");
  const parts = {};
  let at = indexOf(bytes, delimiter, 0);
  while (at >= 0 && !(bytes[at + delimiter.length] === 45 && bytes[at + delimiter.length + 1] === 45)) {
    const headStart = at + delimiter.length + 2; // the CRLF after the delimiter
    const headEnd = indexOf(bytes, blankLine, headStart);
    const next = indexOf(bytes, delimiter, headEnd + 4);
    if (headEnd < 0 || next < 0) throw new Error("the multipart answer is truncated");
    const head = new TextDecoder().decode(bytes.subarray(headStart, headEnd));
    const name = /[;\s]name="([^"]+)"/.exec(head)[1];
    const type = (/content-type:\s*([^\r\n]+)/i.exec(head) || [null, "application/octet-stream"])[1];
    parts[name] = new Blob([bytes.subarray(headEnd + 4, next - 2)], { type }); // a part ends with CRLF
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

// {data: Float32Array, height, width} of a float32 H x W npy file (what the service writes).
export function parseNpy(buffer) {
  const bytes = new Uint8Array(buffer);
  if (bytes[0] !== 0x93 || new TextDecoder().decode(bytes.subarray(1, 6)) !== "NUMPY") {
    throw new Error("the answer is not an npy file");
  }
  const view = new DataView(buffer);
  const [lengthAt, headerStart] = bytes[6] === 1 ? [8, 10] : [8, 12];
  const headerLength = bytes[6] === 1 ? view.getUint16(lengthAt, true) : view.getUint32(lengthAt, true);
  const header = new TextDecoder().decode(bytes.subarray(headerStart, headerStart + headerLength));
  const descr = /'descr':\s*'([^']+)'/.exec(header);
  const shape = /'shape':\s*\(([^)]*)\)/.exec(header);
  const dims = shape ? shape[1].split(",").map((s) => s.trim()).filter(Boolean).map(Number) : [];
  if (!descr || descr[1] !== "<f4" || /'fortran_order':\s*True/.test(header) || dims.length !== 2) {
    throw new Error(`expected a float32 H x W npy array, got ${header.trim()}`);
  }
  const [height, width] = dims;
  const start = headerStart + headerLength;
  // slice(): a copy whose start is aligned for Float32Array whatever the header length
  return { data: new Float32Array(buffer.slice(start, start + 4 * height * width)), height, width };
}

const PLY_TYPES = {
  float: ["getFloat32", 4], float32: ["getFloat32", 4], double: ["getFloat64", 8], float64: ["getFloat64", 8],
  uchar: ["getUint8", 1], uint8: ["getUint8", 1], char: ["getInt8", 1], int8: ["getInt8", 1],
  ushort: ["getUint16", 2], uint16: ["getUint16", 2], short: ["getInt16", 2], int16: ["getInt16", 2],
  uint: ["getUint32", 4], uint32: ["getUint32", 4], int: ["getInt32", 4], int32: ["getInt32", 4],
};

// {positions: Float32Array (x, y, z per point), colors: Uint8Array (r, g, b), count} of a binary
// little-endian PLY whose first element is the vertices (the service's /pointcloud answer).
export function parsePly(buffer) {
  const bytes = new Uint8Array(buffer);
  const marker = encoder.encode("end_header\n");
  const end = indexOf(bytes.subarray(0, Math.min(bytes.length, 4096)), marker, 0);
  if (end < 0) throw new Error("the answer is not a PLY file");
  const lines = new TextDecoder().decode(bytes.subarray(0, end)).split("\n");
  if (lines[0] !== "ply" || !lines.includes("format binary_little_endian 1.0")) {
    throw new Error("the answer is not a binary little-endian PLY file");
  }
  const element = lines.findIndex((line) => line.startsWith("element vertex "));
  const count = Number(lines[element].split(" ")[2]);
  const fields = {};
  let stride = 0;
  for (const line of lines.slice(element + 1)) {
    if (!line.startsWith("property ")) break;
    const [, type, name] = line.split(" ");
    fields[name] = [...PLY_TYPES[type], stride];
    stride += PLY_TYPES[type][1];
  }
  const view = new DataView(buffer, end + marker.length);
  const positions = new Float32Array(3 * count);
  const colors = new Uint8Array(3 * count).fill(200); // grey where the file has no colour
  const read = (name, target, channel) => {
    if (!fields[name]) return;
    const [getter, , offset] = fields[name];
    for (let i = 0; i < count; i++) target[3 * i + channel] = view[getter](i * stride + offset, true);
  };
  ["x", "y", "z"].forEach((name, axis) => read(name, positions, axis));
  ["red", "green", "blue"].forEach((name, channel) => read(name, colors, channel));
  return { positions, colors, count };
}
