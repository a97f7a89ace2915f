"""BC1 codec: bit layout, an independent decoder, encode quality, and the differentiable emulation."""

from __future__ import annotations

import struct

import numpy as np
import pytest
import torch

from mtlx2neural.formats import bc1


def _reference_decode(data: bytes, height: int, width: int) -> np.ndarray:
    """texture2ddecoder's BC1 decode as [H, W, 3] uint8 RGB (it returns BGRA8 rows top to bottom; the
    bit-exact comparisons below would fail with any other reading)."""
    t2d = pytest.importorskip("texture2ddecoder", reason="the independent BC1 decoder is not installed")
    return np.frombuffer(t2d.decode_bc1(data, width, height), np.uint8).reshape(height, width, 4)[..., [2, 1, 0]]


def _to_u8(img: np.ndarray) -> np.ndarray:
    """Our decoded values are exactly k / 255; k as uint8 (asserting exactness)."""
    k = np.rint(img * 255.0)
    assert np.array_equal((k / 255.0).astype(np.float32), img)
    return k.astype(np.uint8)


def _expand_levels(bits: int) -> np.ndarray:
    """All 8-bit values a 5- or 6-bit endpoint channel expands to (bit replication)."""
    q = np.arange(2 ** bits)
    return (q << (8 - bits)) | (q >> (2 * bits - 8))


def _smooth(h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    return np.stack([0.5 + 0.5 * np.sin(6 * x + 2 * y), 0.5 + 0.5 * np.cos(5 * y - 3 * x),
                     0.5 + 0.4 * np.sin(4 * (x + y))], -1).astype(np.float32)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(10 * np.log10(1.0 / np.mean((a.astype(np.float64) - b) ** 2)))


def _block(c0: int, c1: int, indices: list[int]) -> bytes:
    return struct.pack("<HHI", c0, c1, sum(i << (2 * t) for t, i in enumerate(indices)))


def test_constants_and_sizes():
    assert (bc1.BYTES_PER_BLOCK, bc1.CHANNELS, bc1.DXGI_UNORM) == (8, 3, 71)
    for (h, w), blocks in {(1, 1): 1, (4, 4): 1, (5, 7): 4, (8, 12): 6}.items():
        assert len(bc1.encode(np.zeros((h, w, 3), np.float32))) == 8 * blocks


def test_known_block_layout():
    """Red endpoint 0, blue endpoint 1; texel (x, y) uses bits 2*(4y + x); blocks row-major, row 0 on top."""
    idx = [0] * 16
    idx[0:4] = [0, 1, 2, 3]
    idx[4 * 2 + 1] = 3  # texel x=1, y=2
    data = _block(0xF800, 0x001F, idx) + _block(0x07E0, 0x0000, [0] * 16)  # second block: green
    img = _to_u8(bc1.decode(data, 4, 8))
    assert img[0, :4].tolist() == [[255, 0, 0], [0, 0, 255], [170, 0, 85], [85, 0, 170]]
    assert img[2, 1].tolist() == [85, 0, 170] and img[1, 0].tolist() == [255, 0, 0]
    assert (img[:, 4:] == [0, 255, 0]).all()


def test_decode_matches_texture2ddecoder_on_random_blocks():
    """Both modes (random blocks have color0 <= color1 about half the time): bit-exact, because both
    interpolate 8-bit bit-replicated endpoints with truncating integer division."""
    data = np.random.default_rng(0).integers(0, 256, 32 * 32 // 2, np.uint8).tobytes()
    c = np.frombuffer(data, np.uint16).reshape(-1, 4)
    assert (c[:, 0] > c[:, 1]).any() and (c[:, 0] <= c[:, 1]).any()
    assert np.array_equal(_to_u8(bc1.decode(data, 32, 32)), _reference_decode(data, 32, 32))


@pytest.mark.parametrize("shape", [(1, 1), (5, 7), (64, 64)])
def test_encoded_images_decode_identically_in_texture2ddecoder(shape):
    img = np.random.default_rng(1).random((*shape, 3), dtype=np.float32)
    data = bc1.encode(img)
    assert np.array_equal(_to_u8(bc1.decode(data, *shape)), _reference_decode(data, *shape))


def test_encoder_always_uses_the_four_colour_mode():
    rng = np.random.default_rng(2)
    img = np.concatenate([rng.random((32, 32, 3), dtype=np.float32), _smooth(32, 32),
                          np.full((8, 32, 3), 0.3, np.float32), np.zeros((8, 32, 3), np.float32)])
    blocks = np.frombuffer(bc1.encode(img), np.dtype([("c0", "<u2"), ("c1", "<u2"), ("idx", "<u4")]))
    four = blocks["c0"] > blocks["c1"]
    assert four.any()
    single = ~four
    assert (blocks["c0"][single] == blocks["c1"][single]).all() and (blocks["idx"][single] == 0).all()


@pytest.mark.parametrize("value", [0.0, 1.0, 0.5, 0.123, 0.77, 0.031, 0.999])
def test_constant_blocks_round_trip_to_the_nearest_565_value(value):
    img = np.full((4, 8, 3), value, np.float32)
    out = bc1.decode(bc1.encode(img), 4, 8)
    assert (out == out[0, 0]).all()
    for ch, bits in enumerate((5, 6, 5)):
        levels = _expand_levels(bits)
        got = int(np.rint(out[0, 0, ch] * 255))
        assert got in levels  # an endpoint value, not an interpolated one
        assert abs(got - 255 * value) <= np.abs(levels - 255 * value).min() + 1e-9  # 0.5 ties 125 / 130


def test_round_trip_psnr():
    """Measured: smooth field 38.66 dB, uniform white noise 13.78 dB (128x128, seed 3)."""
    smooth = _smooth(128, 128)
    noise = np.random.default_rng(3).random((128, 128, 3), dtype=np.float32)
    assert _psnr(bc1.decode(bc1.encode(smooth), 128, 128), smooth) > 38.0
    assert _psnr(bc1.decode(bc1.encode(noise), 128, 128), noise) > 13.3


def test_representable_blocks_are_found_again():
    """Decoded random 4-colour blocks re-encode exactly when the fit finds their endpoints. Measured
    (seed 7): 98.5% of blocks exact, PSNR 52.26 dB (50.89 dB without the least-squares refits). The
    misses are blocks that happen not to use palette entry 0 or 1, so min/max along the principal
    axis stops short of the true endpoints and the refit cannot reach them."""
    rng = np.random.default_rng(7)
    c = np.sort(rng.integers(0, 65536, (1024, 2)), 1)[:, ::-1]
    c = c[c[:, 0] > c[:, 1]]
    n = len(c)
    blocks = np.zeros(n, np.dtype([("c0", "<u2"), ("c1", "<u2"), ("idx", "<u4")]))
    blocks["c0"], blocks["c1"] = c[:, 0], c[:, 1]
    blocks["idx"] = rng.integers(0, 2 ** 32, n, np.uint64)
    img = bc1.decode(blocks.tobytes(), 4, 4 * n)
    out = bc1.decode(bc1.encode(img), 4, 4 * n)
    exact = (out == img).reshape(4, n, 4, 3).all(axis=(0, 2, 3)).mean()
    assert exact > 0.97
    assert _psnr(out, img) > 51.5


def test_least_squares_endpoints_recover_a_noiseless_line():
    """The refit (and the emulation's continuous path): texels that are exact blends w*a + (1-w)*b of two
    endpoints give back a and b; a block whose indices are all equal falls back to the block mean."""
    rng = np.random.default_rng(8)
    idx = torch.from_numpy(rng.integers(0, 4, (5, 16)))
    a, b = torch.rand(3, 5, 1, dtype=torch.float64), torch.rand(3, 5, 1, dtype=torch.float64)
    w = torch.tensor([1.0, 0.0, 2 / 3, 1 / 3], dtype=torch.float64)[idx]
    e0, e1, fitted = bc1._least_squares(w * a + (1 - w) * b, idx)
    torch.testing.assert_close(e0, a[..., 0])
    torch.testing.assert_close(e1, b[..., 0])
    torch.testing.assert_close(fitted, w * a + (1 - w) * b)
    x = torch.rand(3, 1, 16, dtype=torch.float64)
    e0, e1, fitted = bc1._least_squares(x, torch.full((1, 16), 2))
    torch.testing.assert_close(e0, x.mean(-1))
    torch.testing.assert_close(e1, x.mean(-1))


def test_encode_clamps_out_of_range_values():
    img = np.random.default_rng(4).normal(0.5, 0.8, (8, 8, 3)).astype(np.float32)
    assert bc1.encode(img) == bc1.encode(np.clip(img, 0, 1))
    img[0, 0, 0] = np.nan
    out = bc1.decode(bc1.encode(img), 8, 8)
    assert np.isfinite(out).all() and out.min() >= 0 and out.max() <= 1


@pytest.mark.parametrize("shape", [(1, 1), (2, 3), (5, 7), (64, 64)])
def test_emulate_equals_decode_of_encode(shape):
    img = np.random.default_rng(5).uniform(-0.2, 1.2, (*shape, 3)).astype(np.float32)  # incl. clamping
    img[: shape[0] // 2] = _smooth(*shape)[: shape[0] // 2]
    expected = bc1.decode(bc1.encode(img), *shape)
    x = torch.from_numpy(img).permute(2, 0, 1)
    out = bc1.emulate(x)
    assert out.dtype == torch.float32 and out.shape == x.shape
    assert np.array_equal(out.permute(1, 2, 0).numpy(), expected)
    out64 = bc1.emulate(x.double())
    assert out64.dtype == torch.float64 and torch.equal(out64.float(), out)


def test_emulate_gradient():
    """The gradient is each block channel's upstream gradient projected onto span{1, w}: finite, non-zero,
    a projection (applying it twice changes nothing), and it passes constants (the sum's gradient is 1)."""
    rng = np.random.default_rng(6)
    x = torch.from_numpy(_smooth(16, 16) * 0.8 + 0.1).permute(2, 0, 1).contiguous()
    x = (x + torch.from_numpy(rng.normal(0, 0.02, x.shape).astype(np.float32))).requires_grad_()
    up = torch.from_numpy(rng.normal(0, 1, x.shape).astype(np.float32))
    (g,) = torch.autograd.grad((bc1.emulate(x) * up).sum(), x)
    assert torch.isfinite(g).all() and g.abs().sum() > 0
    (gg,) = torch.autograd.grad((bc1.emulate(x) * g).sum(), x)
    torch.testing.assert_close(gg, g, atol=1e-5, rtol=1e-5)
    (ones,) = torch.autograd.grad(bc1.emulate(x).sum(), x)
    torch.testing.assert_close(ones, torch.ones_like(x), atol=1e-5, rtol=1e-5)
    # partial blocks: the padded texels' share goes back to the edge texels, nothing is lost
    y = x.detach()[:, :5, :7].clone().requires_grad_()
    (gy,) = torch.autograd.grad(bc1.emulate(y).sum(), y)
    assert torch.isfinite(gy).all() and gy.abs().sum() > 0


def test_invalid_arguments():
    with pytest.raises(ValueError):
        bc1.encode(np.zeros((4, 4, 4), np.float32))
    with pytest.raises(ValueError):
        bc1.encode(np.zeros((0, 4, 3), np.float32))
    with pytest.raises(ValueError):
        bc1.decode(bytes(8), 5, 4)
    with pytest.raises(ValueError):
        bc1.emulate(torch.zeros(4, 4, 4))
