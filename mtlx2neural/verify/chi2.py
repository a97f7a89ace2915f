"""Chi-square goodness-of-fit tests for BSDF importance samplers.

This follows the well-known method of Mitsuba 3's and pbrt's ``ChiSquareTest``:

1. Draw ``sample_count`` uniform 2D points, map them through the sampler and
   histogram the resulting directions over equal-area bins of the sphere
   (uniform in ``cos theta`` and ``phi``).
2. Integrate the sampler's claimed pdf over every bin (composite Simpson rule on
   a sub-grid, refined adaptively in bins where halving the sub-grid changes the
   result noticeably) and multiply by ``sample_count`` to get the expected counts.
3. Pool bins whose expected count is below ``min_expected`` (Pearson's statistic
   is only chi-square distributed when every cell has a reasonable expectation),
   compute Pearson's statistic and its p-value, and compare against a Šidák
   corrected significance level.

Conventions (local shading frame): ``z`` is the normal, directions are unit
vectors pointing away from the surface. Histogram row ``i`` covers
``cos theta`` in ``[c_max - (i + 1) * d, c_max - i * d]``, i.e. row 0 is the
ring around the normal and theta grows with the row index; column ``j`` covers
``phi`` in ``[j, j + 1] * 2 pi / phi_bins`` with ``phi = atan2(y, x)`` in
``[0, 2 pi)``.

Samples the sampler marks invalid (or, for ``sphere=False``, that land below
the horizon) are dropped from the histogram but still count towards
``sample_count``, so a sampler that loses mass fails against a pdf that
integrates to one.

Only torch and numpy are needed (the p-value uses the regularised incomplete
gamma function from ``torch.special``); scipy is not required.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["Chi2Result", "chi2_test", "pdf_integral", "sidak_alpha"]

SampleFn = Callable[[torch.Tensor], "tuple[torch.Tensor, torch.Tensor | None]"]
PdfFn = Callable[[torch.Tensor], torch.Tensor]

# Default histogram resolution: Mitsuba/pbrt use 10 cos-theta bins per hemisphere
# and twice as many phi bins (bins are then roughly square near the equator).
_THETA_BINS_PER_HEMISPHERE = 10
_PHI_BINS = 20
# Default Simpson sub-grid: cos-theta step of at most 1/1000 (resolves lobes whose
# width in cos theta is ~0.005, e.g. Phong n=200 or GGX alpha=0.1 reflection) and
# 16 phi intervals per phi bin (a step of ~0.02 rad for 20 bins).
_COS_STEP = 1.0 / 1000.0
_PHI_SUB = 16
# Bin-edge quadrature nodes are moved this fraction of a sub-interval inwards.
_EDGE_EPS = 1e-6
# Adaptive refinement of the bin integrals: a bin is converged when halving its
# Simpson sub-grid changes its expected count by at most _REFINE_TOL Poisson
# standard deviations (sqrt(max(E, min_expected))); otherwise its sub-grid is
# doubled along both axes, at most _REFINE_LEVELS times (16x finer), and never
# beyond _REFINE_MAX_EVALS extra pdf evaluations per level.
_REFINE_TOL = 0.05
_REFINE_LEVELS = 4
_REFINE_MAX_EVALS = 1 << 25
# Points per pdf_fn call while integrating (bounds peak memory for heavy pdfs).
_PDF_BATCH = 1 << 18
# Points per sample_fn call.
_SAMPLE_BATCH = 1 << 20
# A "valid" sample whose length differs from 1 by more than this is a sampler bug
# (float32 normalisation error is ~1e-7, so this only catches real mistakes).
_UNIT_TOL = 1e-3


@dataclass
class Chi2Result:
    """Outcome of :func:`chi2_test`.

    ``observed`` and ``expected`` are the full ``[theta_bins, phi_bins]``
    histograms *before* pooling (row 0 is the ring around +z, see module doc).
    """

    p_value: float
    statistic: float
    dof: int
    passed: bool
    message: str
    observed: np.ndarray
    expected: np.ndarray


def sidak_alpha(significance: float, test_count: int) -> float:
    """Per-test significance level so that ``test_count`` independent tests
    together have a family-wise false-rejection rate of ``significance``.

    ``alpha = 1 - (1 - significance) ** (1 / test_count)``, evaluated with
    ``expm1``/``log1p`` so that ``sidak_alpha(s, 1) == s`` exactly.
    """
    if not 0.0 < significance < 1.0:
        raise ValueError(f"significance must be in (0, 1), got {significance}")
    if int(test_count) != test_count or test_count < 1:
        raise ValueError(f"test_count must be a positive integer, got {test_count}")
    return -math.expm1(math.log1p(-significance) / int(test_count))


# ----------------------------------------------------------------------------
# Quadrature helpers
# ----------------------------------------------------------------------------


def _round_up(n: int, multiple: int) -> int:
    return max(multiple, -(-int(n) // multiple) * multiple)


def _simpson_weights(sub: int, width: float) -> torch.Tensor:
    """Composite Simpson weights for ``sub + 1`` equally spaced nodes spanning ``width``."""
    assert sub % 2 == 0 and sub > 0
    w = torch.full((sub + 1,), 2.0, dtype=torch.float64)
    w[1::2] = 4.0
    w[0] = w[-1] = 1.0
    return w * (width / sub / 3.0)


def _bin_nodes(first_edge: float, step: float, bins: int, sub: int) -> torch.Tensor:
    """Quadrature nodes ``[bins * (sub + 1)]`` for bins ``[first_edge + i*step, first_edge + (i+1)*step]``
    (``step`` may be negative). Every bin gets its own nodes; the two end nodes
    are pulled inside the bin by ``_EDGE_EPS`` of a sub-interval so a pdf that
    jumps at a bin edge (typically at the horizon) is integrated on the correct
    side. The resulting quadrature error is ~``_EDGE_EPS * h * |pdf'|``: nil."""
    offs = torch.arange(sub + 1, dtype=torch.float64) / sub
    offs[0] += _EDGE_EPS / sub
    offs[-1] -= _EDGE_EPS / sub
    edges = first_edge + step * torch.arange(bins, dtype=torch.float64)
    return (edges[:, None] + step * offs[None, :]).reshape(-1)


def _bin_integrals(
    pdf_fn: PdfFn,
    c_max: float,
    dc: float,
    n_theta: int,
    sub_c: int,
    n_phi: int,
    sub_p: int,
    device: torch.device | str | None = None,
) -> tuple[torch.Tensor, torch.Tensor, str | None]:
    """Simpson integral of the pdf over every (cos theta, phi) bin at the given
    sub-resolution and at half of it (same nodes, every other one).

    Returns ``(fine [n_theta, n_phi], coarse [n_theta, n_phi], error message or None)``."""
    dphi = 2.0 * math.pi / n_phi
    nodes_c = _bin_nodes(c_max, -dc, n_theta, sub_c)
    nodes_p = _bin_nodes(0.0, dphi, n_phi, sub_p)
    vals = _eval_pdf_grid(pdf_fn, nodes_c, nodes_p, device)
    err = _check_pdf_values(vals)
    vals = vals.reshape(n_theta, sub_c + 1, n_phi, sub_p + 1)
    fine = torch.einsum("a,b,iajb->ij", _simpson_weights(sub_c, dc), _simpson_weights(sub_p, dphi), vals)
    coarse = torch.einsum(
        "a,b,iajb->ij",
        _simpson_weights(sub_c // 2, dc),
        _simpson_weights(sub_p // 2, dphi),
        vals[:, ::2, :, ::2],
    )
    return fine, coarse, err


def _subset_bin_integrals(
    pdf_fn: PdfFn,
    rows: torch.Tensor,
    cols: torch.Tensor,
    c_max: float,
    dc: float,
    dphi: float,
    sub_c: int,
    sub_p: int,
    device: torch.device | str | None = None,
) -> tuple[torch.Tensor, torch.Tensor, str | None]:
    """Like :func:`_bin_integrals` but for the bins ``(rows[k], cols[k])`` only,
    each on its own ``(sub_c + 1) x (sub_p + 1)`` node grid. Returns ``[B]`` tensors."""
    offs_c = _bin_nodes(0.0, 1.0, 1, sub_c)
    offs_p = _bin_nodes(0.0, 1.0, 1, sub_p)
    wc = _simpson_weights(sub_c, dc)
    wp = _simpson_weights(sub_p, dphi)
    wc2 = _simpson_weights(sub_c // 2, dc)
    wp2 = _simpson_weights(sub_p // 2, dphi)
    per_bin = (sub_c + 1) * (sub_p + 1)
    chunk = max(1, _PDF_BATCH * 4 // per_bin)
    fine, coarse = [], []
    for start in range(0, rows.numel(), chunk):
        r = rows[start : start + chunk].to(torch.float64)
        q = cols[start : start + chunk].to(torch.float64)
        cos_t = (c_max - dc * r)[:, None] - dc * offs_c[None, :]  # [B, sub_c + 1]
        phi = (dphi * q)[:, None] + dphi * offs_p[None, :]  # [B, sub_p + 1]
        c = cos_t[:, :, None].expand(-1, -1, sub_p + 1)
        sn = torch.sqrt(torch.clamp(1.0 - c * c, min=0.0))
        p = phi[:, None, :]
        dirs = torch.stack((sn * torch.cos(p), sn * torch.sin(p), c), dim=-1).reshape(-1, 3)
        vals = _eval_pdf_dirs(pdf_fn, dirs, device)
        err = _check_pdf_values(vals)
        if err is not None:
            return torch.empty(0), torch.empty(0), err
        vals = vals.reshape(-1, sub_c + 1, sub_p + 1)
        fine.append(torch.einsum("a,b,kab->k", wc, wp, vals))
        coarse.append(torch.einsum("a,b,kab->k", wc2, wp2, vals[:, ::2, ::2]))
    return torch.cat(fine), torch.cat(coarse), None


def _directions(cos_theta: torch.Tensor, phi: torch.Tensor) -> torch.Tensor:
    """Outer-product grid of unit vectors, shape ``[len(cos_theta) * len(phi), 3]``."""
    c = cos_theta[:, None].expand(-1, phi.numel())
    s = torch.sqrt(torch.clamp(1.0 - c * c, min=0.0))
    p = phi[None, :]
    return torch.stack((s * torch.cos(p), s * torch.sin(p), c), dim=-1).reshape(-1, 3)


def _eval_pdf_dirs(pdf_fn: PdfFn, dirs: torch.Tensor, device: torch.device | str | None = None) -> torch.Tensor:
    """pdf at float64 directions ``[M, 3]`` as float64 ``[M]`` on the CPU, evaluated
    in large batches (on ``device`` if given)."""
    out = torch.empty(dirs.shape[0], dtype=torch.float64)
    with torch.no_grad():
        for start in range(0, dirs.shape[0], _PDF_BATCH):
            chunk = dirs[start : start + _PDF_BATCH]
            if device is not None:
                chunk = chunk.to(device)
            val = torch.as_tensor(pdf_fn(chunk)).reshape(-1)
            if val.shape != (chunk.shape[0],):
                raise ValueError(
                    f"pdf_fn must return shape [M] for input [M, 3]; got {val.numel()} values "
                    f"for M={chunk.shape[0]}"
                )
            out[start : start + chunk.shape[0]] = val.detach().to("cpu", torch.float64)
    return out


def _eval_pdf_grid(
    pdf_fn: PdfFn, cos_theta: torch.Tensor, phi: torch.Tensor, device: torch.device | str | None = None
) -> torch.Tensor:
    """pdf on the (cos theta, phi) outer-product grid, float64 ``[len(cos_theta), len(phi)]``."""
    vals = _eval_pdf_dirs(pdf_fn, _directions(cos_theta, phi), device)
    return vals.reshape(cos_theta.numel(), phi.numel())


def _check_pdf_values(values: torch.Tensor) -> str | None:
    bad = ~torch.isfinite(values)
    if bool(bad.any()):
        return f"pdf_fn returned {int(bad.sum())} non-finite value(s) on the integration grid"
    neg = values < 0
    if bool(neg.any()):
        return (
            f"pdf_fn returned {int(neg.sum())} negative value(s) on the integration grid "
            f"(min {float(values.min()):.3g})"
        )
    return None


def pdf_integral(
    pdf_fn: PdfFn, *, resolution: int = 512, sphere: bool = True, device: torch.device | str | None = None
) -> float:
    """``∫ pdf dω`` over the sphere (or the upper hemisphere if ``sphere=False``).

    Composite Simpson quadrature in ``(cos theta, phi)`` (whose area element is
    exactly ``dω``): ``resolution`` intervals along ``cos theta`` per hemisphere
    and ``2 * resolution`` along ``phi`` (rounded up to even). Use it to check that
    a pdf integrates to 1 (or to ``1 - absorbed mass``). ``device``: where
    ``pdf_fn`` is called (float64 directions are moved there in batches)."""
    n = _round_up(resolution, 2)
    # The horizon is a bin edge on the sphere, so pdfs that jump there are exact.
    fine, _, err = _bin_integrals(pdf_fn, 1.0, 1.0, 2 if sphere else 1, n, 1, 2 * n, device)
    if err is not None:
        raise ValueError(err)
    return float(fine.sum())


# ----------------------------------------------------------------------------
# The test
# ----------------------------------------------------------------------------


def _draw_samples(
    sample_fn: SampleFn, sample_count: int, seed: int, dtype: torch.dtype, device: torch.device | str | None
) -> tuple[torch.Tensor, torch.Tensor]:
    # numpy's PCG64 seeded through SeedSequence: nearby seeds give independent
    # streams (torch's CPU generator showed a small but measurable bias across
    # seeds 0..299 in float64, which matters when checking p-value calibration).
    rng = np.random.default_rng(int(seed))
    np_dtype = np.float64 if dtype == torch.float64 else np.float32
    dirs, valid = [], []
    with torch.no_grad():
        for start in range(0, sample_count, _SAMPLE_BATCH):
            n = min(_SAMPLE_BATCH, sample_count - start)
            u = torch.from_numpy(rng.random((n, 2), dtype=np_dtype)).to(device=device, dtype=dtype)
            out = sample_fn(u)
            if not isinstance(out, tuple) or len(out) != 2:
                raise ValueError("sample_fn must return a tuple (wo [N, 3], valid [N] bool)")
            wo, ok = out
            wo = torch.as_tensor(wo).detach().to("cpu", torch.float64)
            if wo.shape != (n, 3):
                raise ValueError(f"sample_fn returned wo of shape {tuple(wo.shape)}, expected ({n}, 3)")
            if ok is None:
                ok = torch.ones(n, dtype=torch.bool)
            ok = torch.as_tensor(ok).detach().to("cpu").reshape(-1).bool()
            if ok.shape != (n,):
                raise ValueError(f"sample_fn returned valid of shape {tuple(ok.shape)}, expected ({n},)")
            dirs.append(wo)
            valid.append(ok)
    return torch.cat(dirs), torch.cat(valid)


def _bin_label(i: int, j: int, c_max: float, dc: float, dphi: float) -> str:
    c_hi = c_max - i * dc
    c_lo = c_max - (i + 1) * dc
    return (
        f"bin[{i},{j}] (cos theta {c_lo:+.2f}..{c_hi:+.2f}, "
        f"phi {math.degrees(j * dphi):.0f}..{math.degrees((j + 1) * dphi):.0f} deg)"
    )


def chi2_test(
    sample_fn: SampleFn,
    pdf_fn: PdfFn,
    *,
    sample_count: int = 200_000,
    theta_bins: int | None = None,
    phi_bins: int | None = None,
    significance: float = 0.01,
    test_count: int = 1,
    seed: int = 0,
    min_expected: float = 5.0,
    sphere: bool = True,
    integration_res: int | tuple[int, int] | None = None,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Chi2Result:
    """Pearson chi-square test of ``sample_fn`` against ``pdf_fn``.

    ``sample_fn(u)`` maps ``u [N, 2]`` (uniform in ``[0, 1)``, ``dtype``) to
    ``(wo [N, 3], valid [N] bool)``; ``pdf_fn(wo [M, 3] float64)`` returns the
    solid-angle pdf ``[M]``.

    Bins: ``theta_bins`` equal-width bins in ``cos theta`` over ``[-1, 1]``
    (``sphere=True``) or ``[0, 1]`` (``sphere=False``) times ``phi_bins`` bins in
    ``phi``; every bin has the same solid angle. Defaults: 10 ``cos theta`` bins
    per hemisphere (20 on the sphere) and 20 ``phi`` bins, as in Mitsuba/pbrt.

    ``dtype`` / ``device``: dtype and device of ``u`` handed to ``sample_fn``
    (``u`` comes from numpy's PCG64 seeded with ``seed``); ``pdf_fn`` receives
    float64 directions on ``device``. Histogramming and integration run in
    float64 on the CPU.

    ``integration_res``: Simpson sub-intervals per bin along ``(cos theta, phi)``
    (rounded up to multiples of 4). The default uses a ``cos theta`` step of at
    most 1/1000 and 16 ``phi`` intervals per bin. Every bin is also integrated
    on every other node (half resolution); bins where the two differ by more
    than 0.05 Poisson standard deviations of their expected count get their
    sub-grid doubled along both axes, up to 4 times (adaptive refinement, so
    narrow lobes such as GGX alpha=0.01 are integrated accurately without a huge
    global grid). Bins still unconverged after that raise a ``RuntimeWarning``
    that is also noted in ``message``.

    The significance level is Šidák-corrected for ``test_count`` simultaneous
    tests (:func:`sidak_alpha`); ``passed = p_value > alpha``. The test also fails
    when a sample lands in a bin with zero expected count, when a valid sample
    is not a finite unit vector, or when the pdf is negative / non-finite.
    """
    if sample_count < 1:
        raise ValueError(f"sample_count must be positive, got {sample_count}")
    if min_expected <= 0:
        raise ValueError(f"min_expected must be positive, got {min_expected}")
    alpha = sidak_alpha(significance, test_count)

    hemispheres = 2 if sphere else 1
    n_theta = int(theta_bins) if theta_bins is not None else _THETA_BINS_PER_HEMISPHERE * hemispheres
    n_phi = int(phi_bins) if phi_bins is not None else _PHI_BINS
    if n_theta < 1 or n_phi < 1:
        raise ValueError(f"need at least one bin per axis, got {n_theta} x {n_phi}")
    c_max, c_min = 1.0, (-1.0 if sphere else 0.0)
    dc = (c_max - c_min) / n_theta
    dphi = 2.0 * math.pi / n_phi

    if integration_res is None:
        sub_c = _round_up(math.ceil(dc / _COS_STEP), 4)
        sub_p = _PHI_SUB
    elif isinstance(integration_res, int):
        sub_c = sub_p = _round_up(integration_res, 4)
    else:
        sub_c, sub_p = (_round_up(r, 4) for r in integration_res)

    empty = np.zeros((n_theta, n_phi))

    def fail(msg: str, observed=empty, expected=empty, stat=math.inf, dof=0) -> Chi2Result:
        return Chi2Result(
            p_value=0.0,
            statistic=float(stat),
            dof=int(dof),
            passed=False,
            message="chi2 test FAILED: " + msg,
            observed=np.asarray(observed, dtype=np.float64),
            expected=np.asarray(expected, dtype=np.float64),
        )

    # --- Histogram the samples ------------------------------------------------
    wo, valid = _draw_samples(sample_fn, int(sample_count), seed, dtype, device)
    n_invalid = int((~valid).sum())
    wo = wo[valid]
    finite = torch.isfinite(wo).all(dim=1)
    if not bool(finite.all()):
        return fail(
            f"{int((~finite).sum())} sample(s) marked valid have non-finite directions "
            "(mark failed samples invalid instead)"
        )
    norm = torch.linalg.vector_norm(wo, dim=1)
    off_unit = (norm - 1.0).abs() > _UNIT_TOL
    if bool(off_unit.any()):
        k = int(torch.nonzero(off_unit)[0, 0])
        return fail(
            f"{int(off_unit.sum())} valid sample(s) are not unit vectors "
            f"(e.g. |wo| = {float(norm[k]):.6g}); sample_fn must return normalised directions"
        )
    wo = wo / norm[:, None]
    n_below = 0
    if not sphere:
        above = wo[:, 2] >= 0.0
        n_below = int((~above).sum())
        wo = wo[above]
    cos_t = wo[:, 2].clamp(-1.0, 1.0)
    phi = torch.remainder(torch.atan2(wo[:, 1], wo[:, 0]), 2.0 * math.pi)
    row = ((c_max - cos_t) / dc).floor().long().clamp_(0, n_theta - 1)
    col = (phi / dphi).floor().long().clamp_(0, n_phi - 1)
    observed_t = torch.bincount(row * n_phi + col, minlength=n_theta * n_phi).to(torch.float64)
    observed = observed_t.reshape(n_theta, n_phi).numpy()

    # --- Integrate the pdf over every bin ---------------------------------------
    # The half-resolution result (same nodes, every other one) is a free estimate
    # of the quadrature error.
    integral, integral_coarse, err = _bin_integrals(
        pdf_fn, c_max, dc, n_theta, sub_c, n_phi, sub_p, device
    )
    if err is not None:
        return fail(err, observed=observed)
    n_samples = float(sample_count)

    def unconverged(fine: torch.Tensor, coarse: torch.Tensor) -> torch.Tensor:
        e = fine * n_samples
        d = (fine - coarse).abs() * n_samples
        return d > _REFINE_TOL * torch.sqrt(torch.clamp(e, min=min_expected))

    level_c, level_p = sub_c, sub_p
    for _ in range(_REFINE_LEVELS):
        todo = unconverged(integral, integral_coarse)
        if not bool(todo.any()):
            break
        rows, cols = torch.nonzero(todo, as_tuple=True)
        level_c, level_p = 2 * level_c, 2 * level_p
        if rows.numel() * (level_c + 1) * (level_p + 1) > _REFINE_MAX_EVALS:
            break
        fine, coarse, err = _subset_bin_integrals(
            pdf_fn, rows, cols, c_max, dc, dphi, level_c, level_p, device
        )
        if err is not None:
            return fail(err, observed=observed)
        integral[rows, cols] = fine
        integral_coarse[rows, cols] = coarse
    # Simpson's rule never produces negative weights, so a pdf >= 0 gives >= 0 here.
    expected = (integral * n_samples).numpy()
    expected_coarse = (integral_coarse * n_samples).numpy()
    total_mass = float(integral.sum())
    still = unconverged(integral, integral_coarse).numpy()

    notes = []
    if n_invalid:
        notes.append(f"{n_invalid} of {sample_count} samples invalid (dropped, still counted)")
    if n_below:
        notes.append(f"{n_below} valid samples below the horizon (outside the hemisphere; dropped)")
    if abs(total_mass - 1.0) > 1e-3:
        notes.append(f"pdf integrates to {total_mass:.6f} over the domain")
    if still.any():
        quad = float(
            np.sum((expected - expected_coarse)[still] ** 2 / np.maximum(expected[still], min_expected))
        )
        msg = (
            f"pdf integration may be under-resolved: {int(still.sum())} bin(s) did not converge "
            f"after adaptive refinement (sum of d^2/E over them = {quad:.3g}, d = change when "
            f"halving the sub-grid); raise integration_res"
        )
        warnings.warn(msg, RuntimeWarning, stacklevel=2)
        notes.append(msg)

    # --- Samples in bins the pdf claims are impossible ----------------------------
    impossible = (expected <= 0.0) & (observed > 0)
    if impossible.any():
        idx = np.argwhere(impossible)
        worst = sorted(idx.tolist(), key=lambda ij: -observed[ij[0], ij[1]])[:5]
        where = "; ".join(
            f"{_bin_label(i, j, c_max, dc, dphi)}: {int(observed[i, j])} samples" for i, j in worst
        )
        return fail(
            f"{int(observed[impossible].sum())} sample(s) in {len(idx)} bin(s) where the pdf "
            f"integrates to 0 (the sampler produces directions the pdf calls impossible, or the "
            f"pdf's support there is thinner than the integration grid): {where}",
            observed=observed,
            expected=expected,
        )

    # --- Pool low-expectation bins and compute Pearson's statistic ------------------
    flat_e = expected.ravel()
    flat_o = observed.ravel()
    order = np.argsort(flat_e, kind="stable")
    stat = 0.0
    dof = 0
    pooled_e = pooled_o = 0.0
    pooled_n = 0
    contrib = np.zeros_like(flat_e)
    for k in order:
        e, o = flat_e[k], flat_o[k]
        if e <= 0.0:
            continue  # empty and impossible: contributes nothing
        if e < min_expected or (0.0 < pooled_e < min_expected):
            # Too small on its own, or the pool is still too small: keep pooling
            # (ascending order, so the pool fills up with the smallest bins).
            pooled_e += e
            pooled_o += o
            pooled_n += 1
        else:
            contrib[k] = (o - e) ** 2 / e
            stat += contrib[k]
            dof += 1
    if pooled_e > 0.0:
        stat += (pooled_o - pooled_e) ** 2 / pooled_e
        dof += 1
    # Cell probabilities are fully specified (no fitted parameters): dof = cells - 1.
    dof -= 1
    if pooled_n:
        notes.append(f"pooled {pooled_n} bins with expected count < {min_expected:g}")

    if dof < 1:
        return fail(
            f"only {dof + 1} cell(s) left after pooling; increase sample_count or bins",
            observed=observed,
            expected=expected,
            stat=stat,
            dof=max(dof, 0),
        )

    p_value = float(
        torch.special.gammaincc(
            torch.tensor(dof / 2.0, dtype=torch.float64), torch.tensor(stat / 2.0, dtype=torch.float64)
        )
    )
    passed = p_value > alpha
    head = (
        f"chi2 test {'passed' if passed else 'FAILED'}: statistic {stat:.4g}, dof {dof}, "
        f"p-value {p_value:.4g} {'>' if passed else '<='} alpha {alpha:.4g} "
        f"({n_theta}x{n_phi} bins, {sample_count} samples"
        + (f", Sidak-corrected for {test_count} tests" if test_count > 1 else "")
        + ")"
    )
    if not passed:
        worst = np.argsort(-contrib)[:5]
        detail = "; ".join(
            f"{_bin_label(k // n_phi, k % n_phi, c_max, dc, dphi)}: "
            f"observed {int(flat_o[k])}, expected {flat_e[k]:.1f}"
            for k in worst
            if contrib[k] > 0
        )
        if detail:
            notes.append("largest deviations: " + detail)
    message = head + ("; " + "; ".join(notes) if notes else "")
    return Chi2Result(
        p_value=p_value,
        statistic=float(stat),
        dof=int(dof),
        passed=passed,
        message=message,
        observed=observed,
        expected=expected,
    )
