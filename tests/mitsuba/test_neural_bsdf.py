"""The ``mtlx_neural`` Mitsuba plugin (:mod:`mtlx2neural.mitsuba.neural_bsdf`): its twin agreement with the
torch model that ``load_neural`` builds from the same files, Mitsuba's own chi-square test of its sampling,
a control that the chi-square test rejects a wrong pdf, and the white furnace (directional albedo).

Two kinds of layer: a random, untrained model exported without training (:func:`random_layer`, fast: a
(3, 5)-texel, 6-channel, three-level pyramid of random latents, so odd sizes and periodic wrapping are
exercised), and the bundled samples converted with a short training (``converted_layers``, about 20 s
per sample: the slow tier).

Tolerances and their reasons:

- twin (eval, pdf, sample weight; :data:`TWIN_RTOL`, :data:`TWIN_ATOL`): both sides run float32 on the
  same FP16-exact numbers; only the order of operations differs (the MLPs' accumulation, fused
  multiply-adds), a few ulp per step, which the 64-wide layers and the decoder's exp grow to at most
  1e-4 relative (measured 2e-6 for eval, 3e-5 for pdf, 9e-5 for weights on the converted samples).
  1e-3 leaves room, and is far below any real mismatch (a wrong texel, level or frame changes values by
  percents). Sampled directions: :data:`TWIN_WO_ATOL` per component (measured 1e-5), except for samples
  whose lobe-choosing number lies within 1e-5 of the specular lobe's weight, where float rounding may
  pick the other lobe (sampling is discontinuous there); those are left out. A sample's weight and pdf
  are compared with torch's sample's where wo.z > :data:`STEEP_Z` (nearer the horizon the cosine in the
  weight turns the directions' 1e-7..1e-5 difference into more than 1e-3 relative: measured 1.8e-3 at
  wo.z = 3e-4), and everywhere with torch's eval / pdf at the plugin's own sampled direction;
- furnace: 5 combined standard errors: the plugin's estimate's, measured from its own sample weights
  (2^16 independent samples per query), and the torch estimate's (2^16 scrambled Sobol points), taken
  as the same Monte Carlo standard error (quasi-Monte Carlo does no worse on these integrands). The
  twin test already shows the weights equal for equal random numbers, so this checks the plugin's
  sampling as Mitsuba drives it (PCG32 numbers, ``sample2`` only). The reference's albedo is only
  printed: the test models are undertrained;
- chi-square: Mitsuba's test at its default significance 1%, Sidak-corrected for the cases of a run,
  1M samples, 101 x 202 cells, a 16 x 16 quadrature per cell (:data:`CHI2_IRES` says why).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from conftest import SIMPLE_MTLX
from mitsuba_samples import converted_layers, mi  # noqa: F401
from neural_models import randomise_latents

import mtlx2neural as m2n
from mtlx2neural.contract import ShadingPoint
from mtlx2neural.export import export_asset
from mtlx2neural.export.load import load_neural
from mtlx2neural.material_record import MaterialRecord
from mtlx2neural.model.neural_material import NeuralMaterial

TWIN_RTOL, TWIN_ATOL, TWIN_WO_ATOL = 1e-3, 1e-6, 1e-4
STEEP_Z = 0.02  # sampled wo.z above which a 1e-5 direction difference moves the cosine by < 1e-3 relative
SAMPLE_MATERIALS = [("layered", "CarPaint"), ("layered", "Plastic"), ("textured", "GlazedCeramic"),
                    ("textured", "BrushedMetal"), ("mirror", "PolishedMetal"), ("scene", "Lava"),
                    ("scene", "Leaf"), ("scene", "Gold")]
"""Every material of the four converted samples, with its ``converted_layers`` key."""
THETAS = (0.0, 50.0, 85.0)  # view angles from the normal, degrees: head-on, oblique, grazing
CHI2_UV = [0.3, 0.7]  # a textured point (inside a texel, away from uv 0 where a 1x1 level is read alike)
CHI2_CASES = len(SAMPLE_MATERIALS) * len(THETAS)
CHI2_IRES = 16
"""Points per cell side of the chi-square test's pdf quadrature (Mitsuba's default is 4). The horizon
(cos theta = 0) cuts the middle row of the 101 rows of cells in half, and at grazing view the proxy's
reflection lobe puts much density right above it, where a 4 x 4 trapezoid rule misjudges the cell:
measured on the converted BrushedMetal at 85 degrees with 4M samples, p = 0 with 4 points, 0.71 with 16."""


# ----------------------------------------------------------------------------- layers


def _record(name: str) -> MaterialRecord:
    return MaterialRecord(name, name, "", "0" * 64, flip_mean=0.1, steps=1, device="cpu", train_seconds=1.0)


def export_model(model, folder):
    """Export ``model`` as the material Red of a one-material .mtlx in ``folder``: its neural layer."""
    asset = folder / "thing.mtlx"
    asset.write_text(SIMPLE_MTLX)
    usda, _ = export_asset(asset, [(model, _record("Red"), folder / "thing_neural" / "Red")],
                           folder / "thing_neural", "fast")
    return usda


@pytest.fixture(scope="module")
def random_layer(tmp_path_factory):
    """The neural layer of a random (untrained, seeded) textured model, exported without training."""
    torch.manual_seed(11)
    model = NeuralMaterial((3, 5), in_dim=2, latent_dim=6, frames=2, decoder="2x16")
    randomise_latents(model, 0.7)
    return export_model(model.train(False), tmp_path_factory.mktemp("random"))


def plugin(mi, layer, material=None, **props):  # noqa: F811
    """An ``mtlx_neural`` instance (extra ``props`` passed through, e.g. ``lod``)."""
    d = {"type": "mtlx_neural", "filename": str(layer), **props}
    if material is not None:
        d["material"] = material
    return mi.load_dict(d)


# ----------------------------------------------------------------------------- helpers


def random_queries(n: int, seed: int):
    """Seeded (wi, wo, uv, u): directions uniform on the upper hemisphere, uv in [-1, 2)^2 (so periodic
    wrapping is read), u uniform in [0, 1)^2."""
    g = torch.Generator().manual_seed(seed)

    def dirs():
        v = torch.randn(n, 3, generator=g)
        v = v / v.norm(dim=1, keepdim=True)
        v[:, 2] = v[:, 2].abs()
        return v

    wi, wo = dirs(), dirs()
    return wi, wo, torch.rand(n, 2, generator=g) * 3.0 - 1.0, torch.rand(n, 2, generator=g)


def interaction(mi, wi, uv, duv_dx=None):  # noqa: F811
    """A SurfaceInteraction3f with ``wi`` [N,3] (local frame) and ``uv`` [N,2]; uv partials optional."""
    import drjit as dr  # Local: Dr.Jit is importable only where Mitsuba is (the mi fixture checked)

    si = dr.zeros(mi.SurfaceInteraction3f, wi.shape[0])
    si.wi = mi.Vector3f(wi.numpy().T)
    si.uv = mi.Point2f(uv.numpy().T)
    if duv_dx is not None:
        si.duv_dx = mi.Vector2f(duv_dx.numpy().T)
    return si


def plugin_queries(mi, bsdf, wi, wo, uv, u, duv_dx=None):  # noqa: F811
    """The plugin's eval [N,3], pdf [N], and sample's (wo [N,3], weight [N,3], pdf [N]) as numpy."""
    si = interaction(mi, wi, uv, duv_dx)
    ctx = mi.BSDFContext()
    wo_m = mi.Vector3f(wo.numpy().T)
    f, p = bsdf.eval(ctx, si, wo_m), bsdf.pdf(ctx, si, wo_m)
    bs, weight = bsdf.sample(ctx, si, mi.Float(0.5), mi.Point2f(u.numpy().T))
    return (np.array(f).T, np.array(p), np.array(bs.wo).T, np.array(weight).T, np.array(bs.pdf))


def assert_close(name, got, want, rtol=TWIN_RTOL, atol=TWIN_ATOL):
    want = np.asarray(want)
    err = np.abs(got - want)
    worst = float((err / (atol + rtol * np.abs(want))).max())
    assert worst <= 1.0, (f"{name}: max abs error {err.max():.3g} (at {np.unravel_index(err.argmax(), err.shape)}) "
                          f"is {worst:.3g} times the tolerance")
    return float(err.max()), float((err / np.maximum(np.abs(want), 1e-6)).max())


def assert_twin(mi, layer, material, lods, n=2048, seed=0):  # noqa: F811
    """The plugin equals load_neural's torch model at seeded random wi, wo, uv, u for each integer lod."""
    tm = load_neural(layer, material)
    wi, wo, uv, u = random_queries(n, seed)
    for lod in lods:
        at = ShadingPoint(uv=uv, lod=torch.full((n,), float(lod)))
        with torch.no_grad():
            f_t, p_t = tm.eval(wi, wo, at), tm.pdf(wi, wo, at)
            swo_t, w_t, sp_t = tm.sample(wi, u, at)
            w_spec = tm.sampler(wi, tm.latents(uv, at.lod, torch.zeros(n))).w_spec[:, 0]
        f, p, swo, w, sp = plugin_queries(mi, plugin(mi, layer, material, lod=float(lod)), wi, wo, uv, u)
        errors = {"eval": assert_close(f"{material} lod {lod} eval", f, f_t.numpy()),
                  "pdf": assert_close(f"{material} lod {lod} pdf", p, p_t.numpy())}
        same_lobe = ((u[:, 0] - w_spec).abs() > 1e-5).numpy()
        assert same_lobe.mean() > 0.99
        wo_err = np.abs(swo - swo_t.numpy())[same_lobe].max()
        assert wo_err <= TWIN_WO_ATOL, f"{material} lod {lod}: sampled directions differ by {wo_err:.3g}"
        # Weight and pdf of the sample, against torch's sample where the cosine (of wo.z) does not amplify
        # the directions' rounding difference beyond the tolerance, and against torch's eval / pdf at the
        # plugin's own direction everywhere.
        steep = same_lobe & (swo_t[:, 2] > STEEP_Z).numpy()
        errors["weight"] = assert_close(f"{material} lod {lod} weight", w[steep], w_t.numpy()[steep])
        errors["sample pdf"] = assert_close(f"{material} lod {lod} sample pdf", sp[steep], sp_t.numpy()[steep])
        with torch.no_grad():
            wo_p = torch.from_numpy(swo)
            f_at, p_at = tm.eval(wi, wo_p, at), tm.pdf(wi, wo_p, at)
        w_at = torch.where((p_at > 0)[:, None], f_at / p_at.clamp_min(1e-12)[:, None], torch.zeros_like(f_at))
        errors["weight at own wo"] = assert_close(f"{material} lod {lod} weight at its wo", w, w_at.numpy())
        errors["pdf at own wo"] = assert_close(f"{material} lod {lod} sample pdf at its wo", sp, p_at.numpy())
        print(f"{material} lod {lod}: (max abs, max rel) errors {errors}, sampled wo {wo_err:.3g}")
        assert (p_t > 0).any() and (w_t.abs().sum(1) > 0).any()  # the comparison compared something


# ----------------------------------------------------------------------------- twin


def test_twin_of_the_torch_model_at_every_level(mi, random_layer):  # noqa: F811
    """eval, pdf and sample (wo, weight, pdf) equal the torch model's at each level of a (3, 5) pyramid."""
    assert_twin(mi, random_layer, "Red", lods=(0, 1, 2), seed=1)


@pytest.mark.slow
@pytest.mark.parametrize("material", ["GlazedCeramic", "BrushedMetal"])
def test_twin_of_a_converted_textured_material(mi, converted_layers, material):  # noqa: F811
    assert_twin(mi, converted_layers("textured"), material, lods=(0, 3, 8), seed=2)


def test_ray_differentials_choose_the_level_and_fractional_levels_blend_latents(mi, random_layer):  # noqa: F811
    """With uv partials the lod is log2 of the footprint in level-0 texels: 2^1.5 texels gives lod 1.5,
    the same as the ``lod`` property 1.5, which decodes the latents of levels 1 and 2 blended half and
    half (the plugin's deterministic trilinear lookup; torch picks one level at random instead)."""
    n = 512
    wi, wo, uv, u = random_queries(n, seed=3)
    tm = load_neural(random_layer, "Red")
    _, w = tm.latents.resolution
    duv = torch.zeros(n, 2)
    duv[:, 0] = 2.0 ** 1.5 / w  # along u, in uv units: 2^1.5 level-0 texels
    f_rd, p_rd, *_ = plugin_queries(mi, plugin(mi, random_layer, "Red"), wi, wo, uv, u, duv_dx=duv)
    f_15, p_15, *_ = plugin_queries(mi, plugin(mi, random_layer, "Red", lod=1.5), wi, wo, uv, u)
    assert_close("eval from ray differentials", f_rd, f_15, rtol=1e-4)
    assert_close("pdf from ray differentials", p_rd, p_15, rtol=1e-4)
    with torch.no_grad():
        lat = 0.5 * tm.latents.fetch(uv, torch.full((n,), 1)) + 0.5 * tm.latents.fetch(uv, torch.full((n,), 2))
        f_t = tm.decoder(lat, wi, wo)
        p_t = tm.sampler.pdf(wi, wo, lat)
        f_1 = tm.eval(wi, wo, ShadingPoint(uv=uv, lod=torch.full((n,), 1.0)))
    assert_close("eval at lod 1.5", f_15, f_t.numpy())
    assert_close("pdf at lod 1.5", p_15, p_t.numpy())
    assert np.abs(f_15 - f_1.numpy()).max() > 1e-3  # level 1 alone differs: the blend was tested


def test_below_the_horizon_everything_is_zero(mi, random_layer):  # noqa: F811
    n = 256
    wi, wo, uv, u = random_queries(n, seed=4)
    bsdf = plugin(mi, random_layer, "Red")
    wo_below = wo * torch.tensor([1.0, 1.0, -1.0])
    f, p, *_ = plugin_queries(mi, bsdf, wi, wo_below, uv, u)
    assert not f.any() and not p.any()
    wi_below = wi * torch.tensor([1.0, 1.0, -1.0])
    f, p, swo, weight, sp = plugin_queries(mi, bsdf, wi_below, wo, uv, u)
    assert not f.any() and not p.any() and not weight.any() and not sp.any()
    # Sampled directions below the horizon (the proxy draws some) get weight 0 and pdf 0.
    wi, _, uv, u = random_queries(8192, seed=5)
    _, _, swo, weight, sp = plugin_queries(mi, bsdf, wi, wi, uv, u)
    below = swo[:, 2] <= 0
    assert below.any() and not weight[below].any() and not sp[below].any()
    assert (sp[~below] > 0).all()


def test_a_udim_material_is_refused_at_load_naming_it(mi, tmp_path):  # noqa: F811
    torch.manual_seed(0)
    model = NeuralMaterial((5, 3), in_dim=2, latent_dim=6, decoder="2x16", tiles=[1001, 1002]).train(False)
    layer = export_model(model, tmp_path)
    with pytest.raises(Exception, match=r"Red is a UDIM material .*does not read UDIM"):
        plugin(mi, layer, "Red")


# ----------------------------------------------------------------------------- chi-square


def run_chi2(mi, bsdf_dict, theta_deg, uv, plugin_type="mtlx_neural", test_count=1,  # noqa: F811
             sample_count=1_000_000, seed=7):
    """Mitsuba's chi-square test of the plugin's sample against its pdf at view angle ``theta_deg``
    (in the xz plane) and ``uv``, its random numbers seeded by ``seed``; (passed, p-value, messages)."""
    # Local: Mitsuba's test module imports mitsuba, usable only once the variant is set (the mi fixture).
    from mitsuba.chi2 import BSDFAdapter, ChiSquareTest, SphericalDomain

    th = math.radians(theta_deg)
    sample_func, pdf_func = BSDFAdapter(plugin_type, bsdf_dict, wi=[math.sin(th), 0.0, math.cos(th)], uv=uv)
    chi2 = ChiSquareTest(domain=SphericalDomain(), sample_func=sample_func, pdf_func=pdf_func, sample_dim=3,
                         sample_count=sample_count, res=101, ires=CHI2_IRES, seed=seed)
    passed = chi2.run(test_count=test_count, quiet=True)
    print(f"theta {theta_deg}: passed {passed}, p = {chi2.p_value}; {chi2.messages.strip()}")
    return passed, chi2.p_value, chi2.messages


@pytest.mark.parametrize("theta", [0.0, 85.0])
def test_chi2_random_model(mi, random_layer, theta):  # noqa: F811
    passed, _, messages = run_chi2(mi, {"type": "mtlx_neural", "filename": str(random_layer), "material": "Red"},
                                   theta, CHI2_UV, test_count=2)
    assert passed, messages


@pytest.mark.slow
@pytest.mark.parametrize("theta", THETAS)
@pytest.mark.parametrize("key,material", SAMPLE_MATERIALS)
def test_chi2_every_sample_material(mi, converted_layers, key, material, theta):  # noqa: F811
    layer = converted_layers(key)
    # A seed per case: the cases' statistics are then independent, as the Sidak correction assumes (with
    # one seed for all, the same random numbers made every case's p-value high or low together).
    seed = 100 + SAMPLE_MATERIALS.index((key, material)) * len(THETAS) + THETAS.index(theta)
    passed, _, messages = run_chi2(mi, {"type": "mtlx_neural", "filename": str(layer), "material": material},
                                   theta, CHI2_UV, test_count=CHI2_CASES, seed=seed)
    assert passed, messages


PDF_SKEW = 0.5
"""The control's pdf is the plugin's times (1 + PDF_SKEW * wo.x): still about normalised for a lobe
near the normal, but tilted, which the chi-square test must notice."""


@pytest.fixture(scope="module")
def wrong_pdf_plugin(mi):  # noqa: F811
    """Registers ``mtlx_neural_wrong_pdf``: the plugin with a deliberately skewed ``pdf``."""
    import drjit as dr  # Local: Dr.Jit is importable only where Mitsuba is (the mi fixture checked)

    # Local: the plugin module subclasses mi.BSDF, which exists only once the variant is set.
    from mtlx2neural.mitsuba.neural_bsdf import NeuralBSDF

    class WrongPdf(NeuralBSDF):
        def pdf(self, ctx, si, wo, active=True):
            return NeuralBSDF.pdf(self, ctx, si, wo, active) * dr.maximum(1.0 + PDF_SKEW * wo.x, 0.0)

    mi.register_bsdf("mtlx_neural_wrong_pdf", lambda props: WrongPdf(props))
    return "mtlx_neural_wrong_pdf"


@pytest.mark.parametrize("theta", [0.0, 50.0])
def test_chi2_rejects_a_wrong_pdf(mi, random_layer, wrong_pdf_plugin, theta):  # noqa: F811
    """The control: the same test on a pdf that does not describe the sampling fails."""
    passed, p_value, _ = run_chi2(mi, {"type": wrong_pdf_plugin, "filename": str(random_layer), "material": "Red"},
                                  theta, CHI2_UV, plugin_type=wrong_pdf_plugin)
    assert not passed, f"the chi-square test accepted a skewed pdf (p = {p_value})"


# ----------------------------------------------------------------------------- white furnace


FURNACE_THETAS = (0.0, 45.0, 80.0)
FURNACE_UVS = ((0.3, 0.7), (0.8, 0.15))
MI_SAMPLES, TORCH_SAMPLES = 1 << 16, 1 << 16


def plugin_albedo(mi, bsdf, wi, uv, samples=MI_SAMPLES, seed=5):  # noqa: F811
    """(albedo [Q,3], standard error [Q,3]): the mean of the plugin's sample weights (eval / pdf, the
    cosine included) over ``samples`` independent PCG32 draws per query (``wi`` [Q,3], ``uv`` [Q,2])."""
    import drjit as dr  # Local: Dr.Jit is importable only where Mitsuba is (the mi fixture checked)

    q = wi.shape[0]
    idx = dr.arange(mi.UInt32, q * samples)
    rng = mi.PCG32(size=q * samples, initstate=mi.UInt64(seed), initseq=mi.UInt64(idx))
    si = dr.zeros(mi.SurfaceInteraction3f, q * samples)
    row = idx // samples
    si.wi = dr.gather(mi.Vector3f, mi.Vector3f(wi.numpy().T), row)
    si.uv = dr.gather(mi.Point2f, mi.Point2f(uv.numpy().T), row)
    s1 = rng.next_float32()
    s2 = mi.Point2f(rng.next_float32(), rng.next_float32())
    _, weight = bsdf.sample(mi.BSDFContext(), si, s1, s2)
    w = np.array(weight).reshape(3, q, samples)
    return w.mean(-1).T, w.std(-1).T / math.sqrt(samples)


def furnace_queries():
    wi = torch.tensor([[math.sin(math.radians(t)), 0.0, math.cos(math.radians(t))]
                       for t in FURNACE_THETAS for _ in FURNACE_UVS])
    uv = torch.tensor([uv for _ in FURNACE_THETAS for uv in FURNACE_UVS])
    return wi, uv


def assert_furnace(mi, layer, material, reference_asset=None):  # noqa: F811
    """The plugin's directional albedo equals the torch model's (module docstring's tolerance); with a
    reference asset, prints plugin / reference ratios."""
    wi, uv = furnace_queries()
    a_mi, se = plugin_albedo(mi, plugin(mi, layer, material), wi, uv)
    a_t = load_neural(layer, material).albedo(wi, ShadingPoint(uv=uv), samples=TORCH_SAMPLES).numpy()
    se_torch = se * math.sqrt(MI_SAMPLES / TORCH_SAMPLES)
    tol = 5.0 * np.sqrt(se ** 2 + se_torch ** 2) + 1e-6
    a_ref = None
    if reference_asset is not None:
        a_ref = m2n.load_reference(reference_asset, material).albedo(wi, ShadingPoint(uv=uv), samples=4096).numpy()
    for i in range(wi.shape[0]):
        theta, where = FURNACE_THETAS[i // len(FURNACE_UVS)], FURNACE_UVS[i % len(FURNACE_UVS)]
        line = (f"{material} theta {theta:g} uv {where}: plugin {np.round(a_mi[i], 4)} torch {np.round(a_t[i], 4)} "
                f"|diff| / tolerance {(np.abs(a_mi[i] - a_t[i]) / tol[i]).max():.2g}")
        if a_ref is not None:
            line += f" reference {np.round(a_ref[i], 4)} plugin/reference {np.round(a_mi[i] / np.maximum(a_ref[i], 1e-6), 3)}"
        print(line)
    bad = np.abs(a_mi - a_t) > tol
    assert not bad.any(), f"{material}: plugin albedo {a_mi[bad]} against torch {a_t[bad]} (tolerance {tol[bad]})"
    assert (a_mi > 0).all()


def test_white_furnace_random_model(mi, random_layer):  # noqa: F811
    assert_furnace(mi, random_layer, "Red")


@pytest.mark.slow
@pytest.mark.parametrize("key,material", SAMPLE_MATERIALS)
def test_white_furnace_every_sample_material(mi, converted_layers, key, material):  # noqa: F811
    layer = converted_layers(key)
    asset = layer.with_name(layer.name.replace("_neural.usda", ".usda"))
    assert_furnace(mi, layer, material, reference_asset=asset)
