"""Render one PNG per benchmark (docs/<EnvId>.png) with the envs' rgb_array renderer.

    python docs/make_pictures.py [--out DIR]

Each robot takes 20 env steps (0.5 s) of a fixed sinusoidal stroke in its first control
mode, so the picture shows it deformed on the ground (or in the fluid).
"""

from __future__ import annotations

import argparse
import struct
import zlib
from pathlib import Path

import gymnasium as gym
import numpy as np

import softrom_gym


def write_png(path: Path, rgb: np.ndarray) -> None:
    """A minimal PNG encoder (8-bit RGB), so the docs need no imaging package."""
    h, w, _ = rgb.shape
    raw = b"".join(b"\x00" + rgb[y].tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        body = kind + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
    png += chunk(b"IDAT", zlib.compress(raw, 9)) + chunk(b"IEND", b"")
    path.write_bytes(png)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).parent,
        help="folder for the PNGs (default: docs/, overwriting the committed)",
    )
    out = parser.parse_args().out
    out.mkdir(parents=True, exist_ok=True)
    for name in softrom_gym.BENCHMARKS:
        env = gym.make(f"softrom_gym/{name}", render_mode="rgb_array")
        env.reset(seed=0)
        bound = env.unwrapped.action_bound
        for t in range(20):
            env.step(np.array([np.sin(2 * np.pi * t / 20), 0.0, 0.0], np.float32) * bound)
        frame = env.render()
        write_png(out / f"{name.removesuffix('-v0')}.png", frame)
        print(f"wrote {out / (name.removesuffix('-v0') + '.png')} {frame.shape}")


if __name__ == "__main__":
    main()
