"""Every float32 matrix product asks for full precision, read from the jaxprs.

On NVIDIA GPUs XLA's default float32 product is TensorFloat-32 (10 mantissa bits): it put the
GRT at 2.7e-4 relative error on an H100 and failed 20 tests there. A CPU computes float32
products exactly whatever they request, so no CPU test of the numbers can catch a product
that forgot to ask: these tests read the request (`precision` of each `dot_general`) from the
traced programs, down into scan, cond, checkpoint, shard_map, jit and linear_call bodies.
"""

import functools
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from conftest import compilations, default_then_slow, random_complex
from jax.extend.core import ClosedJaxpr, Jaxpr

import rift_jax as rj
from rift_jax import grt, solvers
from rift_jax._solvers import points as P

HIGHEST = (jax.lax.Precision.HIGHEST, jax.lax.Precision.HIGHEST)


def _subjaxprs(value):
    if isinstance(value, ClosedJaxpr):
        yield value.jaxpr
    elif isinstance(value, Jaxpr):
        yield value
    elif isinstance(value, tuple | list):
        for item in value:
            yield from _subjaxprs(item)


def products(jaxpr) -> list:
    """Every `dot_general` equation of ``jaxpr`` (closed or not) and of all its bodies."""
    if isinstance(jaxpr, ClosedJaxpr):
        jaxpr = jaxpr.jaxpr
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name == "dot_general":
            found.append(eqn)
        for value in eqn.params.values():
            for sub in _subjaxprs(value):
                found.extend(products(sub))
    return found


def inexact_products_below_highest(jaxpr) -> list:
    return [
        eqn
        for eqn in products(jaxpr)
        if jnp.issubdtype(eqn.invars[0].aval.dtype, jnp.inexact)
        and eqn.params["precision"] != HIGHEST
    ]


def assert_exact(jaxpr, what: str, at_least: int = 1):
    found = products(jaxpr)
    assert len(found) >= at_least, f"{what}: expected matrix products, found {len(found)}"
    bad = inexact_products_below_highest(jaxpr)
    assert not bad, f"{what}: {len(bad)} of {len(found)} products lack HIGHEST: {bad[:2]}"


def test_the_reader_finds_products_inside_scan_cond_and_checkpoint():
    """The check itself can fail: default-precision products hidden in each kind of body."""
    a = jnp.ones((4, 4), jnp.float32)

    def fn(x, precision):
        def body(carry, _):
            return carry @ a if precision is None else jnp.matmul(
                carry, a, precision=precision
            ), None

        x = jax.lax.scan(body, x, None, length=2)[0]
        x = jax.lax.cond(x[0, 0] > 0, lambda y: jnp.dot(y, a, precision=precision), jnp.sin, x)
        return jax.checkpoint(lambda y: jnp.einsum("ij,jk->ik", y, a, precision=precision))(x)

    loose = jax.make_jaxpr(lambda x: fn(x, None))(a)
    assert len(products(loose)) == 3 and len(inexact_products_below_highest(loose)) == 3
    exact = jax.make_jaxpr(lambda x: fn(x, jax.lax.Precision.HIGHEST))(a)
    assert_exact(exact, "hand-made", at_least=3)
    assert {"scan", "cond", "remat2"} <= {eqn.primitive.name for eqn in loose.jaxpr.eqns}


@pytest.fixture(scope="module")
def problem():
    radar = rj.Radar(n_frequencies=6, n_tx=3, n_rx=4)
    viewpoints = rj.Viewpoints.grid(3, 2, polar_range=(0.4, 1.2))
    points = rj.grid_points(1.0, 0.5)
    return radar, viewpoints, points, rj.grt_operator(radar, viewpoints, points)


@pytest.mark.parametrize("near_field", [True, False])
@pytest.mark.parametrize("uniform", [True, False])
def test_grt_kernels(problem, near_field, uniform):
    radar, _, points, _ = problem
    tx, rx = rj.antenna_positions(radar, 0.7, 1.1)
    freqs = (
        radar.frequencies if uniform else np.sort(np.random.default_rng(0).uniform(95e9, 1e11, 5))
    )
    rho = jnp.ones(len(points), jnp.complex64)

    def fwd(r):
        return grt.forward(points, r, tx, rx, freqs, near_field=near_field, chunk_size=16)

    signal = fwd(rho)
    assert_exact(jax.make_jaxpr(fwd)(rho), "grt.forward")
    adjoint = jax.make_jaxpr(
        lambda s: grt.adjoint(points, s, tx, rx, freqs, near_field=near_field, chunk_size=16)
    )(signal)
    assert_exact(adjoint, "grt.adjoint")
    # JAX's own transpose of the forward kernel (reverse mode through `forward`)
    gradient = jax.make_jaxpr(jax.grad(lambda r: jnp.sum(jnp.abs(fwd(r)) ** 2), holomorphic=False))
    assert_exact(gradient(rho.real.astype(jnp.complex64)), "grad of grt.forward")


def test_operator_products(problem):
    *_, op = problem
    rho = jnp.asarray(random_complex(np.random.default_rng(0), op.fn.n_points))
    signal = op.mv(rho)
    for what, fn, arg in [
        ("op.mv", op.mv, rho),
        ("op.transpose().mv", op.transpose().mv, signal),
        ("fn.adjoint", op.fn.adjoint, signal),
        ("fn.view", lambda r: op.fn.view(r, 1), rho),
        ("fn.view_adjoint", lambda s: op.fn.view_adjoint(s, 1), signal[1]),
        ("grad through op.mv", jax.grad(lambda r: jnp.sum(jnp.abs(op.mv(r)) ** 2)), rho),
    ]:
        assert_exact(eqx.filter_make_jaxpr(fn)(arg)[0], what)


def test_field_render(problem):
    """The INR's own layers, outside any solver step (final renderings, `evaluate`), and a
    model called alone (on an H100 a bare RiftN was off its Field's rendering by 1e-3)."""
    *_, points, _ = problem
    xyz = jnp.asarray(points, jnp.float32)
    for model in (
        rj.RiftN(width=8, depth=2, key=jax.random.key(0)),
        rj.RiftS(width=8, depth=2, key=jax.random.key(0)),
        rj.HashGrid(width=8, depth=1, levels=2, table_size=64, key=jax.random.key(0)),
    ):
        name = type(model).__name__
        field = rj.Field(model, extent=1.0)
        assert_exact(eqx.filter_make_jaxpr(field.render)(xyz)[0], name)
        alone = eqx.filter_make_jaxpr(lambda p, m=model: jax.vmap(m)(p))(xyz)[0]
        assert_exact(alone, f"{name} alone")


def test_points_lattice_score(problem, x64):
    """The points method's lattice score multiplies in complex64 (it only ranks where Newton
    starts): it too asks for full precision. Without it an H200 ran the score's product in
    TensorFloat-32, more than 1e-5 off the exact score (test_points' any-radar test)."""
    radar, viewpoints, *_ = problem
    geometry = P.Geometry.of(radar, viewpoints)
    tx, rx, k = geometry.arrays()
    shape = (len(viewpoints), radar.n_frequencies, radar.n_tx, radar.n_rx)
    residual, probes = jnp.zeros(shape, jnp.complex128), jnp.zeros((4, 3))
    jaxpr = jax.make_jaxpr(lambda p, r: P._on_lattice("coherent", p, r, tx, rx, k, geometry.law))(
        probes, residual
    )
    assert_exact(jaxpr, "the lattice's coherent score")


def lowered_products(text: str) -> list[str]:
    return [line.strip() for line in text.splitlines() if "stablehlo.dot_general" in line]


@pytest.fixture
def compiled(tmp_path):
    """Every module XLA compiles inside the `with` block, as StableHLO text: what really ran,
    libraries' primitives expanded (lineax expands `linear_solve`, so LSMR's inner products
    and norms, only when lowering)."""

    class Dump:
        def __enter__(self):
            jax.config.update("jax_dump_ir_to", str(tmp_path))
            jax.config.update("jax_dump_ir_modes", "stablehlo")
            return self

        def __exit__(self, *exc):
            jax.config.update("jax_dump_ir_to", "")
            paths = sorted(tmp_path.glob("*.mlir"))
            self.texts = [path.read_text() for path in paths]
            # the programs whose modules hold matrix products (JAX names each file
            # "..._jit_<name>_compile.mlir")
            self.with_products = {
                re.sub(r"^.*?_jit_(.*)_compile\.mlir$", r"\1", path.name)
                for path, text in zip(paths, self.texts, strict=True)
                if "stablehlo.dot_general" in text
            }

    return Dump()


# each solver's budget, and the jitted function its iterations run in; RIFT's 2 epochs are
# 2 steps (one pass over the 5 views each): more would fit the constant field the data
# come from, which the collapse check takes for a collapse. With the robust loss: after 2
# steps complex MSE's residual is still above 1, which the check counts as fitting nothing
# (the loss is elementwise: the products are the same)
ONE_PASS = {"epochs": 2, "epoch_views": None, "loss": "robust"}
METHODS = {
    "kaczmarz": (solvers.kaczmarz, {"iterations": 3}, "_sweep"),
    "lsmr": (solvers.lsmr, {"iterations": 4, "check_every": 2}, "_segment"),
    "gauss-newton": (solvers.gauss_newton, {"iterations": 3, "inner": 2, "tol": 0.0}, "_step"),
    "fista": (solvers.fista, {"iterations": 3, "power_iterations": 1}, "_update"),
    "rift-n": (functools.partial(solvers.rift, model="rift-n"), ONE_PASS, "_step"),
    "rift-s": (functools.partial(solvers.rift, model="rift-s"), ONE_PASS, "_step"),
}


# FISTA and RIFT(N), the candidates of `fit`'s default; the others (~10-20 s each) with
# `-m slow`
@pytest.mark.parametrize("method", default_then_slow(("fista", "rift-n"), METHODS))
def test_what_each_solver_compiles(compiled, caplog, method):
    """A real run of each solver, on a problem size no other test uses (so that it compiles
    here rather than hitting a cache): every product in every module XLA compiled for it
    asks for full precision, and its iteration compiled once per problem shape (FISTA's
    twice: on the held-out λ path's views, whatever the path's length, then on every
    view; a first iterate of another structure or sharding than the next ones' once
    compiled Kaczmarz's, FISTA's and Gauss-Newton's step two or three times). A second
    run on a new signal compiles nothing more; but Gauss-Newton's step, which compiles
    once per run (see
    `rift_jax._solvers.nonlinear`), and with `tol=0` every step runs. The GRT is compiled
    into the iteration and the operator's own products only, never into a diagnostic's
    program of its own."""
    radar = rj.Radar(n_frequencies=7, n_tx=3, n_rx=5)
    viewpoints = rj.Viewpoints.grid(5, 1, polar_range=(0.8, 0.8))
    op = rj.grt_operator(radar, viewpoints, rj.grid_points(1.0, 0.4))
    signal = np.asarray(op.mv(jnp.ones(op.fn.n_points, jnp.complex64)))
    solver, options, step = METHODS[method]

    def run(signal):
        return lambda: solver(op, signal, progress=False, **options).rho

    with compiled:
        first = compilations(caplog, run(signal))
    found = [line for text in compiled.texts for line in lowered_products(text)]
    assert found, f"{method}: no matrix products compiled (cache hit?)"
    bad = [line for line in found if "precision = [HIGHEST, HIGHEST]" not in line]
    assert not bad, f"{method}: {len(bad)} of {len(found)} products: {bad[:2]}"
    count = sum(m.startswith(f"Compiling jit({step})") for m in first)
    shapes = 2 if method == "fista" else 1  # FISTA's λ path runs on 3 of the 5 views first
    assert count == shapes, f"{method} compiled {step} {count} times in one run"
    # the GRT is compiled into the iteration and the operator's own products only: a
    # diagnostic jitted around the operator compiles the whole GRT again (2-5 s each)
    allowed = {step, "render", "__call", "_signals", "adjoint"}  # render: the INR's layers
    extra = sorted(compiled.with_products - allowed)
    assert not extra, f"{method}: {extra} compile the GRT again"
    again = compilations(caplog, run(2 * signal))
    expected = [m for m in again if m.startswith(f"Compiling jit({step})")]
    assert again == (expected if method == "gauss-newton" else []), f"{method} compiled again"


def test_the_lowered_reader_can_fail(compiled):
    """A library-style product compiled without the setting shows up as not HIGHEST."""
    a = jnp.ones((3, 5))
    with compiled:
        jax.jit(lambda x: jnp.vdot(x[0], x[1])).lower(a).compile()
    found = [line for text in compiled.texts for line in lowered_products(text)]
    assert found and all("HIGHEST" not in line for line in found)
