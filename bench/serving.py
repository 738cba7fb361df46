"""What the benchmarks that drive a real ``adsm serve`` share: a free loopback port, PNG and multipart
bodies, and waiting for readiness. A helper module, not a benchmark (it has no ``main``)."""

from __future__ import annotations

import io
import secrets
import socket
import subprocess
import time
import urllib.error
import urllib.request

import numpy as np
from PIL import Image


def free_port() -> int:
    """A loopback port nobody listens on now (the server binds it a moment later)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def png(image: np.ndarray) -> bytes:
    """``image`` (uint8 HxW or HxWx3) as PNG bytes."""
    buffer = io.BytesIO()
    Image.fromarray(image).save(buffer, format="PNG")
    return buffer.getvalue()


def multipart(left: bytes, right: bytes) -> tuple[bytes, str]:
    """A multipart/form-data body with the files ``left`` and ``right``, and its Content-Type."""
    boundary = secrets.token_hex(16)
    body = b""
    for name, data in (("left", left), ("right", right)):
        body += (
            f'--{boundary}\r\nContent-Disposition: form-data; name="{name}"; filename="{name}.png"\r\n'
            "Content-Type: image/png\r\n\r\n"
        ).encode() + data + b"\r\n"
    return body + f"--{boundary}--\r\n".encode(), f"multipart/form-data; boundary={boundary}"


def wait_ready(base: str, server: subprocess.Popen, timeout: float = 600.0) -> float:
    """Seconds until ``base``/readyz answers 200; RuntimeError if the server exits or the time runs out."""
    started = time.perf_counter()
    while time.perf_counter() - started < timeout:
        if server.poll() is not None:
            raise RuntimeError(f"adsm serve exited with code {server.returncode}")
        try:
            with urllib.request.urlopen(f"{base}/readyz", timeout=5):
                return time.perf_counter() - started
        except (urllib.error.URLError, ConnectionError):
            time.sleep(0.2)
    raise RuntimeError(f"adsm serve not ready after {timeout} s")
