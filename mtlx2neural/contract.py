"""The material contract: one interface (:class:`Material`, a ``typing.Protocol``) and one input
convention for every material here (``eval``/``sample``/``pdf``/``albedo``/``describe``).

:class:`~mtlx2neural.reference.ReferenceMaterial`, :class:`~mtlx2neural.model.neural_material.NeuralMaterial`
(and so the ``ExportedNeuralMaterial`` that ``m2n.load_neural`` returns) and
:class:`~mtlx2neural.baseline.analytic_model.AnalyticMaterial` implement :class:`Material`; renderers and
reports use only its methods. *Where* on the surface a query is made is a :class:`ShadingPoint` (texture
coordinates, level of detail, the random number choosing a level, parameter overrides), passed as
``at``; a plain ``[N, 2]`` tensor there means ``ShadingPoint(uv=tensor)`` (:func:`as_point`). The
directional albedo of every material is the one batched estimator :func:`estimate_albedo`.

Conventions (docs/ARCHITECTURE.md), the same for all three materials:

- Directions are ``[N, 3]`` in the local shading frame: z the geometric normal, x the tangent; ``wi``
  points to the viewer, ``wo`` to the light, both away from the surface. ``eval`` returns
  f(wi, wo) * max(0, wo.z) (the cosine included) in linear RGB.
- Directions need not have unit length: every method normalises them the same way. Each vector is
  first divided by its largest absolute component, then by its length, so 1e30- or 1e-30-scaled and
  denormal vectors give the same direction up to rounding, with no overflow or underflow. Vectors of
  unit length to within rounding are used as given.
- A direction is *at or below the horizon* when its normalised z <= 0. A zero vector has no
  direction and counts as below the horizon. There ``eval`` is 0, ``pdf`` is 0, and ``sample``
  returns weight 0 and pdf 0; a *sampled* ``wo`` at or below the horizon also gets weight 0 and pdf 0,
  so ``sample``'s pdf always equals ``pdf(wi, wo)`` of the direction it returns. (``pdf`` therefore
  integrates to 1 minus the probability that ``sample`` fails, not to 1, over the sphere.)
- Any real dtype (float64, float16, bfloat16, integers) on any device is accepted: the numbers are
  normalised in the wider of their dtype and the material's, then converted to the material's dtype
  and device; results come back in the material's dtype (float32 for loaded materials) on its device.
- NaN or +-Inf in any input raises ``ValueError`` naming the argument (nothing is silently replaced);
  so do malformed shapes. Every finite input gives finite outputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import torch

BELOW = (0.0, 0.0, -1.0)  # what a zero vector becomes: a direction straight below the horizon
UNIT_ULPS = 16  # |length^2 - 1| within this many ulps: already unit (a normalised vector is within ~3)


def _tensor(name: str, x) -> torch.Tensor:
    t = x if isinstance(x, torch.Tensor) else torch.as_tensor(x)
    if t.is_complex() or t.dtype == torch.bool:
        raise ValueError(f"{name} must hold real numbers, not {t.dtype}")
    return t


def check_finite(name: str, t: torch.Tensor) -> None:
    """Raise ``ValueError`` naming ``name`` when ``t`` holds NaN or +-Inf."""
    if t.is_floating_point() and not bool(torch.isfinite(t).all()):
        what = "NaN" if bool(torch.isnan(t).any()) else "Inf"
        raise ValueError(f"{name} contains {what}; directions, random numbers and uv must be finite")


def normalize_directions(w: torch.Tensor) -> torch.Tensor:
    """Unit vectors [N,3] from finite float vectors of any length, overflow- and underflow-safe: divided
    by the largest absolute component, then by the length (now in [1, sqrt(3)]). Zero vectors become
    (0, 0, -1), below the horizon.

    Vectors already of unit length to within ``UNIT_ULPS`` ulps of their dtype pass through unchanged,
    so normalising is idempotent: a direction ``sample`` returned gives the very same ``pdf`` when
    passed back, and unit input is used bit for bit as given."""
    n2 = (w * w).sum(-1, keepdim=True)  # inf for huge vectors, which then take the careful path
    unit = (n2 - 1.0).abs() <= UNIT_ULPS * torch.finfo(w.dtype).eps
    m = w.abs().amax(-1, keepdim=True)
    zero = m == 0
    v = w / torch.where(zero, torch.ones_like(m), m)
    v = v / v.norm(dim=-1, keepdim=True).clamp_min(1.0)
    return torch.where(unit, w, torch.where(zero, v.new_tensor(BELOW), v))


def _working_dtype(t: torch.Tensor, dtype: torch.dtype) -> torch.dtype:
    return torch.promote_types(t.dtype, dtype) if t.is_floating_point() else dtype


def prepare_direction(name: str, w, dtype: torch.dtype, device) -> torch.Tensor:
    """One direction argument: checked ([N,3], real, finite), normalised, in ``dtype`` on ``device``."""
    t = _tensor(name, w)
    if t.dim() != 2 or t.shape[-1] != 3:
        raise ValueError(f"{name} must be an [N, 3] tensor of directions, got shape {list(t.shape)}")
    check_finite(name, t)
    t = normalize_directions(t.to(_working_dtype(t, dtype)))
    return t.to(device=device, dtype=dtype)


def prepare_directions(wi, wo, dtype: torch.dtype, device) -> tuple[torch.Tensor, torch.Tensor]:
    """``(wi, wo)`` as unit vectors [N,3] in ``dtype`` on ``device`` (the module's conventions):
    ValueError for NaN/Inf, a shape other than [N,3], or differing N."""
    wi = prepare_direction("wi", wi, dtype, device)
    wo = prepare_direction("wo", wo, dtype, device)
    if wi.shape[0] != wo.shape[0]:
        raise ValueError(f"wi and wo must have the same number of rows; wi has {wi.shape[0]}, wo {wo.shape[0]}")
    return wi, wo


def prepare_values(name: str, x, dtype: torch.dtype, device, rows: int | None = None,
                   width: tuple[int, ...] | None = None) -> torch.Tensor | None:
    """A non-direction input (``u``, ``uv``, ``lod``, ...) checked finite and converted to ``dtype`` on
    ``device``; ``None`` stays ``None``. ``rows``: the number of rows it must have; ``width``: the
    allowed sizes of its last axis (a 2-D tensor then)."""
    if x is None:
        return None
    t = _tensor(name, x)
    if width is not None and (t.dim() != 2 or t.shape[-1] not in width):
        shapes = " or ".join(f"[N, {k}]" for k in width)
        raise ValueError(f"{name} must be an {shapes} tensor, got shape {list(t.shape)}")
    if rows is not None and (t.dim() == 0 or t.shape[0] != rows):
        raise ValueError(f"{name} must have {rows} rows (one per direction), got shape {list(t.shape)}")
    check_finite(name, t)
    return t.to(device=device, dtype=dtype)


def above_horizon(*ws: torch.Tensor) -> torch.Tensor:
    """[N,1] bool: every one of the (normalised) directions ``ws`` has z > 0."""
    ok = ws[0][:, 2:3] > 0
    for w in ws[1:]:
        ok = ok & (w[:, 2:3] > 0)
    return ok


def zero_below_horizon(x: torch.Tensor, wi: torch.Tensor, wo: torch.Tensor) -> torch.Tensor:
    """``x`` ([N] or [N, C]) where both ``wi`` and ``wo`` are above the horizon, else 0."""
    ok = above_horizon(wi, wo)
    return torch.where(ok[:, 0] if x.dim() == 1 else ok, x, torch.zeros_like(x))


# ----------------------------------------------------------------------------- where: ShadingPoint


@dataclass(frozen=True, eq=False)
class ShadingPoint:
    """Where on the surface a material is queried: one row per direction (``N`` rows), every field optional.

    - ``uv`` [N,2]: texture coordinates, MaterialX's convention ((0, 0) an image's bottom-left). ``None``:
      the material's behaviour without coordinates, as before this type existed: the reference evaluates
      its graph at (0.5, 0.5), the neural and analytic materials read (0, 0), which for a uniform
      material (one 1x1 texel) is the only texel.
    - ``lod`` [N]: level of detail in latent-pyramid levels, i.e. log2 of the footprint in finest-level
      texels (0 = finest). ``None``: the finest level. The reference is not prefiltered and ignores it
      (it point-samples its graph at ``uv``).
    - ``u_level`` [N]: uniform random numbers in [0, 1) choosing between the two levels nearest ``lod``
      (level floor(lod), or the next one with probability frac(lod)). ``None``: 0 for every row, the
      deterministic choice of before. Ignored by the reference.
    - ``params``: ``{name: [N, width]}`` parameter overrides by name (``CompiledMaterial.parameters()``),
      e.g. prefiltered values from a ``ParameterStack``; the reference's ``params=`` of before. ``None``
      (or ``{}``): none. Materials without named parameters (neural, analytic) reject a non-empty dict.

    Frozen; equality is identity (fields are tensors). Values are checked (finite, shapes) by the
    material that receives the point, with errors naming the field."""

    uv: torch.Tensor | None = None
    lod: torch.Tensor | None = None
    u_level: torch.Tensor | None = None
    params: dict | None = None

    def repeat_rows(self, k: int, n: int) -> ShadingPoint:
        """This point with every row repeated ``k`` times in place (row i becomes rows i*k .. i*k+k-1),
        to match directions repeated with ``repeat_interleave(k, 0)``. Only fields with ``n`` rows are
        repeated; others (``None``, or a single row that broadcasts) are kept as they are."""

        def rep(x):
            if isinstance(x, torch.Tensor) and x.dim() > 0 and x.shape[0] == n:
                return x.repeat_interleave(k, 0)
            return x

        params = None if self.params is None else {key: rep(v) for key, v in self.params.items()}
        return ShadingPoint(rep(self.uv), rep(self.lod), rep(self.u_level), params)

    def select(self, index: torch.Tensor, n: int) -> ShadingPoint:
        """This point's rows ``index`` (a [M] integer tensor into its ``n`` rows), to match directions
        selected with ``wi[index]``. As in :meth:`repeat_rows`, only fields with ``n`` rows are selected."""

        def pick(x):
            if isinstance(x, torch.Tensor) and x.dim() > 0 and x.shape[0] == n:
                return x[index.to(x.device)]
            return x

        params = None if self.params is None else {key: pick(v) for key, v in self.params.items()}
        return ShadingPoint(pick(self.uv), pick(self.lod), pick(self.u_level), params)


def as_point(at) -> ShadingPoint:
    """``at`` as a :class:`ShadingPoint`: ``None`` -> ``ShadingPoint()`` (the material's defaults), a
    ShadingPoint -> itself, anything else (a tensor or array-like, expected ``[N, 2]``) ->
    ``ShadingPoint(uv=at)``, so callers that pass uv positionally keep working. A dict is refused with a
    ``TypeError`` (parameter overrides go in ``ShadingPoint(params=...)``)."""
    if at is None:
        return ShadingPoint()
    if isinstance(at, ShadingPoint):
        return at
    if isinstance(at, dict):
        raise TypeError("at must be a ShadingPoint or a [N, 2] uv tensor; pass parameter overrides as "
                        "ShadingPoint(params=...)")
    return ShadingPoint(uv=at)


def prepare_point(at, dtype: torch.dtype, device) -> ShadingPoint:
    """``at`` (see :func:`as_point`) with ``uv`` ([N,2]), ``lod`` and ``u_level`` checked finite and
    converted to ``dtype`` on ``device`` (``ValueError`` naming the field otherwise); ``params`` as given."""
    p = as_point(at)
    return ShadingPoint(prepare_values("uv", p.uv, dtype, device, width=(2,)),
                        prepare_values("lod", p.lod, dtype, device),
                        prepare_values("u_level", p.u_level, dtype, device), p.params)


def reject_params(p: ShadingPoint, who: str) -> None:
    """``ValueError`` when ``p`` carries parameter overrides: ``who`` has no parameters by name."""
    if p.params:
        raise ValueError(f"{who} has no named parameters to override; ShadingPoint.params must be None "
                         f"or empty (got {sorted(p.params)})")


# ----------------------------------------------------------------------------- what: the Material protocol


@runtime_checkable
class Material(Protocol):
    """What every material offers: the reference, the neural and the analytic one alike.

    All methods take directions ``[N, 3]`` in the local shading frame: z is the normal the renderer
    provides (the geometric normal; a normal map belongs to the material), x the tangent. ``wi`` points
    towards the viewer, ``wo`` towards the light (or is the sampled direction); both point away from the
    surface. Directions of any length and real dtype are accepted and normalised (module docstring);
    at or below the horizon (z <= 0, or a zero vector) every value is 0. ``at`` is where on the surface
    (:class:`ShadingPoint`, a ``[N, 2]`` uv tensor, or ``None``). NaN/Inf input raises ``ValueError``
    naming the argument; results come back in the material's dtype on its device.
    """

    def eval(self, wi, wo, at=None) -> torch.Tensor:
        """f(wi, wo) * max(0, cos theta_o): ``[N, 3]`` linear RGB, the cosine *included*. cos theta_o is
        ``wo.z``, or ``wo``'s cosine to the material's own shading normal where it has one (a normal map,
        the analytic model's slopes). 0 when ``wi`` or ``wo`` is at or below the horizon (z <= 0)."""
        ...

    def sample(self, wi, u, at=None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Importance-sample ``wo`` from uniform numbers ``u`` ``[N, 2]`` (or ``[N, 3]``: the third picks a
        lobe where the material has a discrete choice, else it is ignored). Returns ``(wo [N, 3] unit,
        weight [N, 3] = eval / pdf (so the cosine is included), pdf [N] per steradian)``; a ``wo`` at or
        below the horizon, a failed sample, or ``wi`` at or below the horizon give weight 0 and pdf 0, so
        ``pdf`` equals :meth:`pdf` of the returned direction."""
        ...

    def pdf(self, wi, wo, at=None) -> torch.Tensor:
        """Solid-angle density ``[N]`` (1/sr) of :meth:`sample` at ``wo``; 0 when ``wi`` or ``wo`` is at or
        below the horizon (so it integrates to 1 minus the probability of a failed sample). No cosine."""
        ...

    def albedo(self, wi, at=None, samples: int = 256, seed: int = 0) -> torch.Tensor:
        """Directional albedo ``[N, 3]``: the integral of :meth:`eval` (cosine included) over ``wo``, by
        :func:`estimate_albedo` with ``samples`` points seeded by ``seed``; 0 when ``wi`` is at or below
        the horizon."""
        ...

    def describe(self) -> dict:
        """A JSON-serialisable summary of the material (what it is made of, its sizes and settings)."""
        ...


# ----------------------------------------------------------------------------- albedo, once for all


ALBEDO_DIMENSIONS = 3  # Sobol dimensions: two for the direction, one for a lobe choice (ignored if none)


def estimate_albedo(material: Material, wi: torch.Tensor, at=None, samples: int = 256,
                    seed: int = 0) -> torch.Tensor:
    """Directional albedo ``[N, 3]`` of ``material`` at ``wi`` (unit ``[N, 3]``, local frame, towards the
    viewer, already in the material's dtype and device): the mean of ``material.sample``'s weights
    (eval / pdf, cosine included) over ``samples`` scrambled Sobol points (3-D, seeded by ``seed``; the
    same points for every row). One batched ``sample`` call over ``N * samples`` rows, no loop, no
    gradients. 0 where ``wi`` is at or below the horizon (``sample`` gives weight 0 there).

    ``at`` (see :func:`as_point`): fields with ``N`` rows are repeated for the samples, others broadcast.
    An unbiased estimate when the sampler covers the material's support; its error shrinks faster than
    1/sqrt(samples) for smooth integrands (quasi-Monte Carlo)."""
    n = wi.shape[0]
    point = as_point(at).repeat_rows(samples, n)
    sobol = torch.quasirandom.SobolEngine(ALBEDO_DIMENSIONS, scramble=True, seed=seed).draw(samples)
    u = sobol.to(device=wi.device, dtype=wi.dtype).repeat(n, 1)
    with torch.no_grad():
        _, weight, _ = material.sample(wi.repeat_interleave(samples, 0), u, point)
    return weight.view(n, samples, 3).mean(1)


# ----------------------------------------------------------------------------- beside the BRDF: emission, opacity


def emission_of(material, at) -> torch.Tensor | None:
    """Emitted radiance ``[N, 3]`` (linear RGB in the working space, the same in every direction, so no
    cosine) of ``material`` at ``at``, or None when it emits nothing. A material that can emit offers
    ``emission(at)``, which returns None when it does not; the :class:`Material` protocol does not require it.
    MaterialX's hardware shading adds it to the reflected light, and the sum is weighted by the opacity."""
    fn = getattr(material, "emission", None)
    return None if fn is None else fn(at)


def coverage_of(material, at) -> torch.Tensor | None:
    """Coverage ``[N]`` in [0, 1] of ``material`` at ``at`` (the share of the surface that is there; the
    rest shows what lies behind), or None when it is opaque. A material with an opacity offers
    ``opacity(at)``: None when opaque, else the value a consumer uses directly. A cut-out's opacity map is
    alpha-tested: the material's ``alpha_cutoff`` (when set) turns it into 0 or 1 here."""
    fn = getattr(material, "opacity", None)
    alpha = None if fn is None else fn(at)
    if alpha is None:
        return None
    cutoff = getattr(material, "alpha_cutoff", None)
    return (alpha >= cutoff).to(alpha.dtype) if cutoff is not None else alpha.clamp(0.0, 1.0)
