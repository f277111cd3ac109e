"""Python side of the overhead comparison (issue 17): the 1024² AP DRR of phantom L3 (no discs), raster
backend, timed in a Python loop. Compare with `cargo bench --bench all -- python_overhead` (criterion, the
same render from Rust). Prints the mean and median per call (ms) of

* ``Renderer.render(view)`` — renderer built once, the same work criterion times, plus the call,
  the GIL release and the hand-over of the float32 image to numpy;
* ``render_mesh(scene, view)`` — the one-shot function, which also builds the scene each call;

and the binding's own cost per call: wall time minus the render time the library measures inside it.

Usage: target/pyenv/bin/python python/benches/overhead.py [SAMPLES]
"""

import os
import statistics
import sys
import time

import spinedrr


def timed(f, n):
    for _ in range(5):  # warm-up, as criterion's
        f()
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        f()
        out.append((time.perf_counter() - t0) * 1e3)
    return out


def main():
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 50
    scene = spinedrr.phantom("L3", discs=False).scene
    view = spinedrr.CArm.default().view("ap")
    renderer = spinedrr.Renderer(scene)
    print(f"cores: {os.cpu_count()}, samples: {n}")
    for name, f in [("Renderer.render", lambda: renderer.render(view)), ("render_mesh", lambda: spinedrr.render_mesh(scene, view))]:
        t = timed(f, n)
        print(f"{name:16} mean {statistics.fmean(t):7.2f} ms  median {statistics.median(t):7.2f} ms  min {min(t):7.2f} ms")
    # The same calls against the library's own clock: wall time of the Python call minus the render time
    # the library measured inside it is what the binding adds (argument checks, GIL release and
    # re-acquisition, numpy hand-over), whatever else the machine is doing.
    walls, inner = [], []
    for _ in range(n):
        t0 = time.perf_counter()
        _, stats = renderer.render(view, stats=True)
        walls.append((time.perf_counter() - t0) * 1e3)
        inner.append(stats["render_ms"])
    over = [w - r for w, r in zip(walls, inner)]
    print(f"binding overhead per call: median {statistics.median(over):.3f} ms, "
          f"{100 * statistics.median(over) / statistics.median(inner):.2f} % of the median render ({statistics.median(inner):.2f} ms)")


if __name__ == "__main__":
    main()
