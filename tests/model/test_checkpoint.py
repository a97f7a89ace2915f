"""Loading trained neural materials from the trainer's checkpoint.pt."""

from __future__ import annotations

import dataclasses
import re

import pytest
import torch

from mtlx2neural.contract import ShadingPoint
from mtlx2neural.errors import InputError
from mtlx2neural.model.checkpoint import load_checkpoint, model_arguments
from mtlx2neural.model.neural_material import NeuralMaterial
from mtlx2neural.train.config import TrainConfig


def _save_like_trainer(model, folder, cfg=None, **extra):
    """The dict Trainer.save writes (minus optimiser/rng state the loader ignores)."""
    cfg = dataclasses.asdict(cfg or TrainConfig())
    folder.mkdir(parents=True, exist_ok=True)
    torch.save({"model": model.state_dict(), "step": 10, "baked": True, "history": [], "config": cfg, **extra},
               folder / "checkpoint.pt")
    return folder / "checkpoint.pt"


def _randomised(model, seed=0):
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.copy_(torch.randn(p.shape, generator=g) * 0.3)
    return model


@pytest.mark.parametrize("resolution, in_dim, decoder, frames, albedo", [
    ((6, 10), 5, "2x16", 2, False),
    ((1, 1), 0, "3x64", 3, True),  # a uniform material: encoder input width 1 but in_dim 0
])
def test_roundtrip_gives_identical_outputs(tmp_path, resolution, in_dim, decoder, frames, albedo):
    model = _randomised(NeuralMaterial(resolution, in_dim, 8, frames, decoder, albedo)).train(False)
    cfg = TrainConfig(decoder=decoder, frames=frames, albedo_head=albedo)
    path = _save_like_trainer(model, tmp_path / "Mat", cfg)
    for where in (path, tmp_path / "Mat"):  # the file or its folder
        loaded = load_checkpoint(where)
        assert not loaded.training and loaded.checkpoint_step == 10
        assert loaded.encoder.in_dim == in_dim
        assert tuple(loaded.latents.levels[0].shape[1:]) == resolution
        g = torch.Generator().manual_seed(1)
        wi = torch.nn.functional.normalize(torch.randn(64, 3, generator=g).abs(), dim=-1)
        wo = torch.nn.functional.normalize(torch.randn(64, 3, generator=g).abs(), dim=-1)
        uv, lod, u = torch.rand(64, 2, generator=g), torch.rand(64, generator=g) * 3, torch.rand(64, generator=g)
        at = ShadingPoint(uv=uv, lod=lod, u_level=u)
        with torch.no_grad():
            assert torch.equal(loaded.eval(wi, wo, at), model.eval(wi, wo, at))
            assert torch.equal(loaded.pdf(wi, wo, at), model.pdf(wi, wo, at))


def test_unknown_config_keys_are_ignored(tmp_path):
    model = NeuralMaterial((4, 4), 3)
    cfg = dataclasses.asdict(TrainConfig()) | {"ablation": "no_frames", "some_future_knob": 3}
    torch.save({"model": model.state_dict(), "config": cfg}, tmp_path / "checkpoint.pt")
    assert isinstance(load_checkpoint(tmp_path), NeuralMaterial)
    assert "some_future_knob" not in model_arguments(model.state_dict(), cfg)


def test_missing_or_corrupt_checkpoint_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match=re.escape(str(tmp_path / "nowhere" / "checkpoint.pt"))):
        load_checkpoint(tmp_path / "nowhere")
    bad = tmp_path / "bad" / "checkpoint.pt"
    bad.parent.mkdir()
    bad.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match=re.escape(str(bad))):
        load_checkpoint(bad)
    torch.save({"weights": 1}, bad)
    with pytest.raises(InputError, match="not a mtlx2neural checkpoint"):
        load_checkpoint(bad)
    state = NeuralMaterial((4, 4), 3).state_dict()
    del state["decoder.net.0.bias"]
    torch.save({"model": state}, bad)
    with pytest.raises(InputError, match="does not match"):
        load_checkpoint(bad)


def test_unbaked_checkpoint_warns(tmp_path):
    _save_like_trainer(NeuralMaterial((2, 2), 1), tmp_path, baked=False)
    with pytest.warns(UserWarning, match="before the latent bake"):
        load_checkpoint(tmp_path)


def test_frameless_ablation_round_trips(tmp_path):
    torch.manual_seed(0)
    m = NeuralMaterial((4, 4), 3, 8, frames=0, decoder="2x16")
    torch.save({"model": m.state_dict(), "config": {"analytic_cosine": True}}, tmp_path / "checkpoint.pt")
    back = load_checkpoint(tmp_path)
    assert back.decoder.frames == 0 and back.decoder.frame_layer is None
    wi = torch.nn.functional.normalize(torch.rand(64, 3) + 0.1, dim=-1)
    uv = torch.rand(64, 2)
    assert torch.equal(back.eval(wi, wi, uv), m.eval(wi, wi, uv))


def test_checkpoint_from_before_the_analytic_cosine_keeps_its_learned_cosine(tmp_path):
    """A config without ``analytic_cosine`` is a model whose network learned f * cos itself: loading it
    must not multiply by the cosine a second time; a current config's model does multiply."""
    torch.manual_seed(0)
    old = NeuralMaterial((2, 2), 3, analytic_cosine=False).train(False)
    cfg = {k: v for k, v in dataclasses.asdict(TrainConfig()).items() if k != "analytic_cosine"}
    torch.save({"model": old.state_dict(), "config": cfg}, tmp_path / "checkpoint.pt")
    back = load_checkpoint(tmp_path)
    assert back.decoder.analytic_cosine is False
    wi = torch.nn.functional.normalize(torch.rand(32, 3) + 0.1, dim=-1)
    wo = torch.nn.functional.normalize(torch.rand(32, 3) + 0.1, dim=-1)
    uv = torch.rand(32, 2)
    with torch.no_grad():
        assert torch.equal(back.eval(wi, wo, uv), old.eval(wi, wo, uv))
        new = NeuralMaterial((2, 2), 3)  # the default: the cosine is analytic
        new.load_state_dict(old.state_dict())
        # Same weights, so the two differ by exactly the factor wo.z (float32 rounding: 1e-6 relative).
        torch.testing.assert_close(new.eval(wi, wo, uv), old.eval(wi, wo, uv) * wo[:, 2:3], rtol=1e-6, atol=0)


def test_a_checkpoint_from_before_the_sharp_lobe_shades_as_it_did(tmp_path):
    """An environment head of 6 outputs (the sampler's specular and diffuse lobes only) loads as a head of 9
    whose sharp lobe carries nothing: every consumer reads three lobes, and the other two are unchanged."""
    from mtlx2neural.codegen.spec import spec_from_state

    torch.manual_seed(4)
    model = NeuralMaterial((4, 4), in_dim=2, latent_dim=8, frames=2, decoder="2x16", environment_head=True)
    state = {k: v.clone() for k, v in model.state_dict().items()}
    last = max(int(k.split(".")[2]) for k in state if k.startswith("decoder.environment.") and k.endswith(".weight"))
    for kind in ("weight", "bias"):  # the legacy head: the last 6 outputs of today's
        state[f"decoder.environment.{last}.{kind}"] = state[f"decoder.environment.{last}.{kind}"][3:]
    torch.save({"model": state, "step": 10, "baked": True, "history": [], "config": dataclasses.asdict(TrainConfig())},
               tmp_path / "checkpoint.pt")
    legacy = load_checkpoint(tmp_path / "checkpoint.pt")
    wi = torch.nn.functional.normalize(torch.rand(64, 3) + torch.tensor([0.0, 0.0, 0.5]), dim=-1)
    at = ShadingPoint(uv=torch.rand(64, 2))
    with torch.no_grad():
        _, _, c = legacy.environment_lobes(wi, at)
        _, _, want = model.environment_lobes(wi, at)
    assert float(c[:, 0].abs().max()) < 1e-40  # exp(-103): 0 in FP16, a denormal in FP32
    torch.testing.assert_close(c[:, 1:], want[:, 1:], rtol=0.0, atol=0.0)
    assert spec_from_state({k: v for k, v in state.items() if k.startswith(("decoder.", "sampler."))}
                           ).environment[-1].shape[0] == 9  # the shader generators read the same three lobes
