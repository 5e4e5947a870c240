"""The fast step, the floating frame's and the penalty ground's allocate nothing once a
rollout worker has seen its sizes.

Counted in a child process by a malloc shim preloaded in front of glibc's (Linux only, built
with the C compiler that built the core): a rollout's heap allocations are counted for two
horizons of the same controls after a warm-up rollout over the longer one. The binding's own
per-call allocations (the output arrays) do not depend on the horizon, the steps' would:
before the worker kept its contact buffers (scratch.h) a walking step made ~90-130 of them,
the floating frame's first build 23-31 (products evaluated into heap temporaries), and a
penalty step 750-890 (its Newton iterations' and line search's vectors, its per-node
products).
The reference solver is not counted: its cubature kernel is kept as issue #8 found it, the
yardstick the fast kernels are measured against, and it allocates.
"""

import json
import os
import shutil
import subprocess
import sys
import textwrap

import pytest

_SHIM = r"""
#include <stddef.h>
static long count = 0;
#define COUNT __atomic_add_fetch(&count, 1, __ATOMIC_RELAXED)
extern void *__libc_malloc(size_t);
extern void *__libc_calloc(size_t, size_t);
extern void *__libc_realloc(void *, size_t);
extern void *__libc_memalign(size_t, size_t);
void *malloc(size_t n) { COUNT; return __libc_malloc(n); }
void *calloc(size_t a, size_t b) { COUNT; return __libc_calloc(a, b); }
void *realloc(void *p, size_t n) { COUNT; return __libc_realloc(p, n); }
int posix_memalign(void **p, size_t a, size_t n) {
  COUNT;
  *p = __libc_memalign(a, n);
  return *p ? 0 : 12;
}
void *aligned_alloc(size_t a, size_t n) { COUNT; return __libc_memalign(a, n); }
long softrom_test_malloc_count(void) { return __atomic_load_n(&count, __ATOMIC_RELAXED); }
"""

_CHILD = textwrap.dedent(
    """
    import ctypes, json, sys
    import numpy as np
    from softrom_gym.robots import beam
    from softrom_gym.rom import build_reduced_model

    counter = ctypes.CDLL(sys.argv[1]).softrom_test_malloc_count
    counter.restype = ctypes.c_long
    robot = beam()
    swim = dict(contact="none", gravity=[0.0, 0.0, 0.0], fluid_density=1000.0)
    cases = {
        "walk": dict(contact="staggered"),
        "swim": swim,
        "floating walk": dict(contact="staggered", frame="floating"),
        "floating swim": dict(swim, frame="floating"),
        "penalty walk": dict(contact="penalty"),
        "floating penalty walk": dict(contact="penalty", frame="floating"),
    }
    out = {}
    for name, settings in cases.items():
        model = build_reduced_model(robot, control_basis=np.eye(20)[:, :3], **settings)
        t = np.arange(400) * model.dt
        amp = 0.8 * np.sqrt(model.total_mass) * 9.81
        u = amp * np.sin(2 * np.pi * 2.0 * t[:, None] - 2 * np.pi * np.arange(3) / 3)
        u = u[None]
        start = model.rest_state()
        model.rollout(start, u, threads=1)  # the worker meets every size of these steps
        counts = []
        for horizon in (100, 400):
            before = counter()
            r = model.rollout(start, u[:, :horizon], threads=1)
            counts.append(counter() - before)
            assert not r["diverged"].any()
        out[name] = counts
    json.dump(out, sys.stdout)
    """
)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="an LD_PRELOAD malloc shim")
def test_steps_do_not_allocate(tmp_path):
    cc = shutil.which(os.environ.get("CC", "cc")) or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler for the malloc shim")
    (tmp_path / "shim.c").write_text(_SHIM)
    shim = tmp_path / "libshim.so"
    subprocess.run([cc, "-O2", "-shared", "-fPIC", "-o", str(shim), str(tmp_path / "shim.c")],
                   check=True, capture_output=True)  # fmt: skip
    env = {**os.environ, "LD_PRELOAD": str(shim)}
    proc = subprocess.run([sys.executable, "-c", _CHILD, str(shim)], env=env,
                          capture_output=True, text=True)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    counts = json.loads(proc.stdout)
    for case, (short, long) in counts.items():
        # 300 more steps (~30,000 allocations before). The call's own allocations are a few
        # dozen, and differ by a handful between horizons: numpy serves small arrays (the
        # shorter call's rewards) from its own cache and asks malloc for larger ones.
        assert long - short <= 20, (case, short, long)
        assert short < 200, (case, short)  # and the call's own stay a handful
