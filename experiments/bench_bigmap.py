"""Peak memory of reading a huge ``map_server`` map at a coarser resolution.

Writes an N x N binary PGM (the ``map_server`` format; 0.05 m/pixel, walls on a 20 m grid with
2 m doors) a strip at a time into a temporary folder, then reads it with
``jaxplore.maps.load_world(yaml, res)`` in a fresh subprocess per source tree and resolution,
and reports the child's peak RSS during the read (``VmHWM``, reset after the imports), its RSS
before the read, the wall time, and a digest of the grid (the trees must agree). The image is
deleted afterwards. A PNG (``--format png``) is written from the whole array by Pillow.

    python experiments/bench_bigmap.py --size 20000 --res 1.0 native --format pgm \
        --trees main=/work/main this=. --out experiments/results/bench_bigmap.md
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = r"""
import hashlib, json, sys, time
from jaxplore.maps.worlds import load_world
import jaxplore.maps.io
def status_kib(key):
  return next(int(line.split()[1]) for line in open("/proc/self/status") if line.startswith(key))
imports_peak = status_kib("VmHWM") * 1024
# Reset the peak to what is resident now (Linux: clear_refs 5), so that the imports' own
# transient peak does not hide a read smaller than it.
with open("/proc/self/clear_refs", "w") as f:
  f.write("5")
base = status_kib("VmRSS") * 1024
t0 = time.perf_counter()
grid = load_world(sys.argv[1], res=None if sys.argv[2] == "native" else float(sys.argv[2]))
wall = time.perf_counter() - t0
peak = status_kib("VmHWM") * 1024
digest = hashlib.sha256(grid.occupied.tobytes()).hexdigest()[:12]
try:  # the memory check's estimate, where the tree has one for a streamed read
  from pathlib import Path
  image = jaxplore.maps.io._MapImage(Path(sys.argv[1]).parent / sys.argv[3], "bench")
  estimate = image.read_bytes(grid.shape)
  image.close()
except AttributeError:
  estimate = None
print(json.dumps({"module": jaxplore.maps.io.__file__, "shape": list(grid.shape), "base": base,
                  "imports_peak": imports_peak,
                  "peak": peak, "wall": wall, "digest": digest,
                  "free": float(grid.free.mean()), "estimate": estimate}))
"""


def map_blocks(n: int, block_rows: int = 500):
  """An n x n map's pixels by blocks of rows: 254 free, 0 on the border and on walls every 400
  pixels with 40-pixel doors."""
  cols = np.arange(n)[None, :]
  door_cols = (cols % 400 >= 180) & (cols % 400 < 220)
  for row0 in range(0, n, block_rows):
    rows = np.arange(row0, min(n, row0 + block_rows))[:, None]
    door_rows = (rows % 400 >= 180) & (rows % 400 < 220)
    wall = (((rows % 400 == 0) & ~door_cols) | ((cols % 400 == 0) & ~door_rows)
            | (rows == 0) | (rows == n - 1) | (cols == 0) | (cols == n - 1))
    yield np.where(wall, 0, 254).astype(np.uint8)


def write_image(path: Path, n: int) -> None:
  """A binary PGM written a block at a time; a PNG (Pillow) from the whole array."""
  if path.suffix == ".pgm":
    with open(path, "wb") as f:
      f.write(f"P5\n# CREATOR: bench_bigmap.py 0.050 m/pix\n{n} {n}\n255\n".encode())
      for block in map_blocks(n):
        f.write(block.tobytes())
  else:
    from PIL import Image
    Image.MAX_IMAGE_PIXELS = None
    Image.fromarray(np.concatenate(list(map_blocks(n)))).save(path, compress_level=1)


def measure(tree: Path, yaml_path: Path, res: str, image: str) -> dict:
  env = dict(os.environ, PYTHONPATH=str(tree))
  t0 = time.perf_counter()
  proc = subprocess.run([sys.executable, "-c", CHILD, str(yaml_path), res, image], 
                        cwd=tree, env=env, capture_output=True, text=True)
  total = time.perf_counter() - t0
  if proc.returncode:
    return {"error": proc.stderr.strip().splitlines()[-1][:300], "total": total}
  return dict(json.loads(proc.stdout.strip().splitlines()[-1]), total=total)


def main():
  parser = argparse.ArgumentParser()
  parser.add_argument("--size", type=int, default=20000)
  parser.add_argument("--res", nargs="+", default=["1.0"], help="m/cell, or 'native'")
  parser.add_argument("--trees", nargs="+", default=["this=."], help="label=path of a checkout")
  parser.add_argument("--format", choices=["pgm", "png"], default="pgm")
  parser.add_argument("--tmp", default=tempfile.gettempdir())
  parser.add_argument("--out", default=None)
  args = parser.parse_args()
  rows = []
  with tempfile.TemporaryDirectory(dir=args.tmp, prefix="bench_bigmap_") as folder:
    yaml_path = Path(folder) / "big.yaml"
    image = f"big.{args.format}"
    yaml_path.write_text(f"image: {image}\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n"
                         "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    t0 = time.perf_counter()
    write_image(Path(folder) / image, args.size)
    print(f"wrote {args.size} x {args.size} {args.format} in {time.perf_counter() - t0:.0f} s",
          flush=True)
    for res in args.res:
      for label, tree in (spec.split("=", 1) for spec in args.trees):
        row = dict(measure(Path(tree).resolve(), yaml_path, res, image), tree=label, res=res)
        print(row, flush=True)
        rows.append(row)
  kind = "binary PGM" if args.format == "pgm" else "PNG"
  lines = [f"{args.size} x {args.size} {kind} (0.05 m/pixel, {args.size**2 / 1e6:.0f} Mpx, "
           f"{args.size**2 / 2**20:.0f} MiB of pixels) read by `load_world(yaml, res)`:", "",
           "| tree | res (m/cell) | grid | peak RSS (MiB) | RSS before the read (MiB) | "
           "peak - before (MiB) | check's estimate (MiB) | load (s) | grid digest |",
           "|---|---|---|---|---|---|---|---|---|"]
  for r in rows:
    if "error" in r:
      lines.append(f"| {r['tree']} | {r['res']} | error: {r['error']} | | | | | | |")
      continue
    estimate = "-" if r["estimate"] is None else f"{r['estimate'] / 2**20:.0f}"
    lines.append(f"| {r['tree']} | {r['res']} | {r['shape'][1]} x {r['shape'][0]} "
                 f"| {r['peak'] / 2**20:.0f} | {r['base'] / 2**20:.0f} "
                 f"| {(r['peak'] - r['base']) / 2**20:.0f} | {estimate} | {r['wall']:.1f} "
                 f"| {r['digest']} |")
  text = "\n".join(lines)
  print(text)
  if args.out:
    Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
  main()
