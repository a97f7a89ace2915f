"""The measured (MERL) material against the closed-form BRDF its table was written from: values at the
table's nodes and between them, reciprocity, the sampler's chi-square test, weight = eval / pdf, the
albedo, and the material contract's input rules."""

from __future__ import annotations

import math

import pytest
import torch
from conftest import random_dirs
from merl_samples import ggx_plastic, write_sample
from sampler_checks import sampler_chi2

from mtlx2neural.contract import Material
from mtlx2neural.formats.merl import directions_of, node_angles, read_merl
from mtlx2neural.reference.measured import MeasuredMaterial, load_measured
from mtlx2neural.verify.chi2 import pdf_integral

BRDFS = {
    "plastic": ggx_plastic(kd=(0.45, 0.25, 0.08), alpha=0.25),
    "glossy_metal": ggx_plastic(kd=(0.0, 0.0, 0.0), ks=1.0, alpha=0.08, f0=0.9),
}
WI_ANGLES = (20.0, 70.0)
N_CHI2 = len(BRDFS) * len(WI_ANGLES)


@pytest.fixture(scope="module")
def tables(tmp_path_factory):
    folder = tmp_path_factory.mktemp("merl")
    return {name: read_merl(write_sample(folder / f"{name}.binary", brdf)) for name, brdf in BRDFS.items()}


def _wi(deg: float) -> torch.Tensor:
    t = math.radians(deg)
    return torch.tensor([[math.sin(t) * 0.8, math.sin(t) * 0.6, math.cos(t)]])


def test_is_a_material(tables):
    assert isinstance(MeasuredMaterial(tables["plastic"]), Material)


@pytest.mark.parametrize("interpolation", ["linear", "nearest"])
def test_nodes_return_the_tabulated_brdf(tables, interpolation):
    # At a node both lookups return the node's value; float64 material, so only the trigonometry of the
    # node's directions rounds (1e-9 relative).
    m = MeasuredMaterial(tables["plastic"], dtype=torch.float64, interpolation=interpolation)
    g = torch.Generator().manual_seed(5)
    th, td, pd = (torch.as_tensor(a) for a in node_angles())
    i, j, k = (torch.randint(0, n, (500,), generator=g) for n in (90, 90, 180))
    wi, wo = directions_of(th[i], td[j], pd[k])
    # the node must be unambiguous: a tiny nudge towards its cell keeps truncation on it
    wi, wo = directions_of(th[i] + 1e-9, td[j] + 1e-9, pd[k] + 1e-9)
    keep = (wi[:, 2] > 1e-3) & (wo[:, 2] > 1e-3)
    expected = BRDFS["plastic"](wi, wo) * wo[:, 2:3]
    torch.testing.assert_close(m.eval(wi, wo)[keep], expected[keep], rtol=1e-6, atol=1e-9)


def test_interpolation_between_nodes_follows_the_closed_form(tables):
    # Away from the horizon (where unmeasured entries, read as 0, are blended in) trilinear interpolation
    # on the table follows the smooth closed form closely: measured median 0.01 %, 99th percentile
    # 0.30 %, largest 0.57 % (plastic, alpha 0.25, 20000 pairs). Bounds: about three times those.
    m = MeasuredMaterial(tables["plastic"])
    wi, wo = random_dirs(20000, seed=11), random_dirs(20000, seed=12)
    keep = (wi[:, 2] > 0.2) & (wo[:, 2] > 0.2)
    wi, wo = wi[keep], wo[keep]
    expected = (BRDFS["plastic"](wi.double(), wo.double()) * wo[:, 2:3].double()).float()
    rel = ((m.eval(wi, wo) - expected).abs() / expected).amax(-1)
    assert float(rel.median()) < 0.0005 and float(torch.quantile(rel, 0.99)) < 0.01, (rel.median(), rel.quantile(0.99))


def test_reciprocal_and_zero_below_the_horizon(tables):
    m = MeasuredMaterial(tables["glossy_metal"])
    wi, wo = random_dirs(4096, seed=3), random_dirs(4096, seed=4)
    f_io = m.eval(wi, wo) / wo[:, 2:3]
    f_oi = m.eval(wo, wi) / wi[:, 2:3]
    # the fold maps (wi, wo) and (wo, wi) to the same phi_d up to float32 rounding at the fold's seam
    torch.testing.assert_close(f_io, f_oi, rtol=2e-3, atol=1e-5)
    down = wo * torch.tensor([1.0, 1.0, -1.0])
    assert float(m.eval(wi, down).abs().max()) == 0.0 and float(m.pdf(wi, down).abs().max()) == 0.0


@pytest.mark.parametrize("deg", WI_ANGLES)
@pytest.mark.parametrize("name", list(BRDFS))
def test_sampler_chi2(tables, name, deg):
    result = sampler_chi2(MeasuredMaterial(tables[name]), _wi(deg), N_CHI2)
    assert result.passed, result.message


@pytest.mark.parametrize("name", list(BRDFS))
def test_weight_is_eval_over_pdf_and_pdf_is_normalised(tables, name):
    m = MeasuredMaterial(tables[name])
    wi = random_dirs(4096, seed=3)
    u = torch.rand(4096, 3, generator=torch.Generator().manual_seed(4))
    wo, weight, pdf = m.sample(wi, u)
    ok = pdf > 1e-6
    # the same float32 maths in separate calls: a few ulps
    torch.testing.assert_close(weight[ok], m.eval(wi, wo)[ok] / pdf[ok, None], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(pdf, m.pdf(wi, wo), rtol=1e-5, atol=1e-6)
    w45 = _wi(45.0)
    total = pdf_integral(lambda d: m.pdf(w45.expand(d.shape[0], 3), d.float()).double(), resolution=512)
    n = 1 << 17
    wo, _, pdf = m.sample(w45.expand(n, 3), torch.rand(n, 3, generator=torch.Generator().manual_seed(6)))
    above = float((pdf > 0).double().mean())
    # pdf integrates to the probability of a sample that did not fail; quadrature ~1e-3 for these
    # lobes, the Monte Carlo fraction ~1e-3 (one sigma): 1 % bound
    assert above > 0.8 and abs(total - above) < 0.01, (total, above)


@pytest.mark.parametrize("name", list(BRDFS))
def test_albedo_matches_uniform_hemisphere_integration(tables, name):
    # The importance-sampled estimator (4096 Sobol points) against 400k uniform hemisphere directions.
    # The uniform estimate's relative standard error is under 1 % for these lobes (the glossy metal's
    # peak dominates its variance), the sampled one's smaller: 3 % bound.
    m = MeasuredMaterial(tables[name])
    wi = torch.tensor([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8], [0.95, 0.0, 0.312]])
    sampled = m.albedo(wi, samples=4096)
    n = 400_000
    w = random_dirs(n, seed=21)
    uniform = torch.stack([(m.eval(v.expand(n, 3), w) * 2 * math.pi).mean(0) for v in wi])
    torch.testing.assert_close(sampled, uniform, rtol=0.03, atol=1e-3)


def test_contract_inputs(tables, tmp_path):
    m = MeasuredMaterial(tables["plastic"])
    wi = random_dirs(4, seed=1)
    with pytest.raises(ValueError, match="wo"):
        m.eval(wi, torch.full((4, 3), float("nan")))
    # unnormalised and float64 input give the same values as unit float32 input
    torch.testing.assert_close(m.eval(wi.double() * 1e20, wi * 3.0), m.eval(wi, wi))
    assert m.describe()["dims"] == [90, 90, 180]
    path = write_sample(tmp_path / "p.binary")
    assert load_measured(path, interpolation="nearest").interpolation == "nearest"
