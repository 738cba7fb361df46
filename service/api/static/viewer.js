// An interactive point-cloud view in plain WebGL 1 (no library: a point shader and an orbit camera are
// ~150 lines, a vendored three.js module would be 1.2 MB). Drag (or one finger) to rotate, wheel (or
// pinch) to zoom, arrow keys and +/- too, double-click or reset() to go back to the camera's own view.
"use strict";

const VERTEX_SHADER = `
attribute vec3 position;
attribute vec3 color;
uniform mat4 transform;
uniform float pointSize;
varying vec3 pointColor;
void main() {
  gl_Position = transform * vec4(position, 1.0);
  gl_PointSize = pointSize;
  pointColor = color;
}`;
const FRAGMENT_SHADER = `
precision mediump float;
varying vec3 pointColor;
void main() { gl_FragColor = vec4(pointColor, 1.0); }`;
const BACKGROUND = [0.12, 0.12, 0.14];
const MAX_PITCH = 1.5; // radians: stop short of looking straight down, where yaw turns into roll

// 4x4 matrices, column-major as WebGL takes them.
const multiply = (a, b) => {
  const out = new Float32Array(16);
  for (let column = 0; column < 4; column++) {
    for (let row = 0; row < 4; row++) {
      let sum = 0;
      for (let k = 0; k < 4; k++) sum += a[k * 4 + row] * b[column * 4 + k];
      out[column * 4 + row] = sum;
    }
  }
  return out;
};
const translation = (x, y, z) => new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, x, y, z, 1]);
const rotationX = (a) => new Float32Array([1, 0, 0, 0, 0, Math.cos(a), Math.sin(a), 0,
  0, -Math.sin(a), Math.cos(a), 0, 0, 0, 0, 1]);
const rotationY = (a) => new Float32Array([Math.cos(a), 0, -Math.sin(a), 0, 0, 1, 0, 0,
  Math.sin(a), 0, Math.cos(a), 0, 0, 0, 0, 1]);
// The camera frame (x right, y down, z forward) seen by WebGL's eye (x right, y up, looking along -z).
const CAMERA_TO_EYE = new Float32Array([1, 0, 0, 0, 0, -1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1]);

function perspective(fovY, aspect, near, far) {
  const f = 1 / Math.tan(fovY / 2);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) / (near - far), -1,
    0, 0, (2 * far * near) / (near - far), 0]);
}

function median(values, offset) {
  const sample = [];
  const step = Math.max(1, Math.floor(values.length / 3 / 20000));
  for (let i = offset; i < values.length; i += 3 * step) sample.push(values[i]);
  sample.sort((a, b) => a - b);
  return sample.length ? sample[sample.length >> 1] : 0;
}

export class CloudViewer {
  constructor(canvas) {
    this.canvas = canvas;
    this.gl = canvas.getContext("webgl", { antialias: false, preserveDrawingBuffer: true });
    this.count = 0;
    this.pointSize = 2;
    this.pointers = new Map();
    if (!this.gl) return; // no WebGL here: available is false and the page says so
    const gl = this.gl;
    this.program = gl.createProgram();
    for (const [type, source] of [[gl.VERTEX_SHADER, VERTEX_SHADER], [gl.FRAGMENT_SHADER, FRAGMENT_SHADER]]) {
      const shader = gl.createShader(type);
      gl.shaderSource(shader, source);
      gl.compileShader(shader);
      gl.attachShader(this.program, shader);
    }
    gl.linkProgram(this.program);
    this.buffers = { position: gl.createBuffer(), color: gl.createBuffer() };
    gl.enable(gl.DEPTH_TEST);
    this.listen();
    new ResizeObserver(() => this.draw()).observe(canvas);
  }

  get available() {
    return Boolean(this.gl);
  }

  // positions: Float32Array of x, y, z (metres, camera frame); colors: Uint8Array r, g, b; fovY: the
  // camera's vertical field of view in radians (so that the first view looks like the left image).
  show({ positions, colors, count }, { fovY = 0.9 } = {}) {
    if (!this.gl) return;
    const gl = this.gl;
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buffers.position);
    gl.bufferData(gl.ARRAY_BUFFER, positions, gl.STATIC_DRAW);
    gl.bindBuffer(gl.ARRAY_BUFFER, this.buffers.color);
    gl.bufferData(gl.ARRAY_BUFFER, colors, gl.STATIC_DRAW);
    this.count = count;
    this.fovY = fovY;
    this.target = [0, 1, 2].map((axis) => median(positions, axis));
    this.reset();
  }

  clear() {
    this.count = 0;
    this.draw();
  }

  reset() {
    this.yaw = 0;
    this.pitch = 0;
    // From the camera's own position: the cloud's median point straight ahead at its own depth.
    this.distance = Math.max(1e-3, this.target ? this.target[2] : 1);
    this.draw();
  }

  setPointSize(size) {
    this.pointSize = size;
    this.draw();
  }

  draw() {
    if (!this.gl) return;
    const gl = this.gl;
    const ratio = window.devicePixelRatio || 1;
    const width = Math.max(1, Math.round(this.canvas.clientWidth * ratio));
    const height = Math.max(1, Math.round(this.canvas.clientHeight * ratio));
    if (this.canvas.width !== width || this.canvas.height !== height) {
      this.canvas.width = width;
      this.canvas.height = height;
    }
    gl.viewport(0, 0, width, height);
    gl.clearColor(...BACKGROUND, 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    if (!this.count) return;
    const [tx, ty, tz] = this.target;
    const view = [translation(0, 0, -this.distance), rotationX(this.pitch), rotationY(this.yaw),
      CAMERA_TO_EYE, translation(-tx, -ty, -tz)].reduce(multiply);
    const projection = perspective(this.fovY, width / height, this.distance / 1000, this.distance * 1000);
    gl.useProgram(this.program);
    gl.uniformMatrix4fv(gl.getUniformLocation(this.program, "transform"), false, multiply(projection, view));
    gl.uniform1f(gl.getUniformLocation(this.program, "pointSize"), this.pointSize * ratio);
    for (const [name, buffer, type, normalized] of [["position", this.buffers.position, gl.FLOAT, false],
      ["color", this.buffers.color, gl.UNSIGNED_BYTE, true]]) {
      const location = gl.getAttribLocation(this.program, name);
      gl.bindBuffer(gl.ARRAY_BUFFER, buffer);
      gl.enableVertexAttribArray(location);
      gl.vertexAttribPointer(location, 3, type, normalized, 0, 0);
    }
    gl.drawArrays(gl.POINTS, 0, this.count);
  }

  rotate(dx, dy) {
    this.yaw += dx;
    this.pitch = Math.min(MAX_PITCH, Math.max(-MAX_PITCH, this.pitch + dy));
    this.draw();
  }

  zoom(factor) {
    this.distance *= factor;
    this.draw();
  }

  listen() {
    const canvas = this.canvas;
    canvas.addEventListener("pointerdown", (event) => {
      canvas.setPointerCapture(event.pointerId);
      this.pointers.set(event.pointerId, [event.clientX, event.clientY]);
    });
    canvas.addEventListener("pointermove", (event) => {
      const previous = this.pointers.get(event.pointerId);
      if (!previous) return;
      const spanBefore = this.span();
      this.pointers.set(event.pointerId, [event.clientX, event.clientY]);
      if (this.pointers.size === 1) {
        this.rotate((event.clientX - previous[0]) * 0.01, -(event.clientY - previous[1]) * 0.01);
      } else if (this.pointers.size === 2 && spanBefore > 0) {
        this.zoom(spanBefore / Math.max(1, this.span())); // pinch
      }
    });
    for (const type of ["pointerup", "pointercancel"]) {
      canvas.addEventListener(type, (event) => this.pointers.delete(event.pointerId));
    }
    canvas.addEventListener("wheel", (event) => {
      event.preventDefault();
      this.zoom(Math.exp(event.deltaY * 0.0015));
    }, { passive: false });
    canvas.addEventListener("dblclick", () => this.reset());
    canvas.addEventListener("keydown", (event) => {
      const moves = { ArrowLeft: [-0.1, 0], ArrowRight: [0.1, 0], ArrowUp: [0, 0.1], ArrowDown: [0, -0.1] };
      if (moves[event.key]) this.rotate(...moves[event.key]);
      else if (event.key === "+" || event.key === "=") this.zoom(0.9);
      else if (event.key === "-") this.zoom(1 / 0.9);
      else return;
      event.preventDefault();
    });
  }

  span() {
    const [a, b] = [...this.pointers.values()];
    return b ? Math.hypot(a[0] - b[0], a[1] - b[1]) : 0;
  }
}
