"""HDR FLIP (flip-evaluator) that never ends the process, for any pair of images.

flip-evaluator's native code calls the C library's ``exit()`` ("Start exposure must be smaller
than stop exposure!") when it derives its exposure range from a reference that is black or
nearly so: it places the range's start at ``log2(x / Ymax)`` for the reference's largest
luminance ``Ymax`` and its stop at the median luminance floored at float32's epsilon (about
1.19e-7), so any ``Ymax`` below that floor orders the range backwards. Measured on
flip-evaluator 1.7: a reference whose brightest pixel has luminance 1e-6 is evaluated, 1e-12
and 0 end the process (rc 255).

:func:`hdr_flip` checks the images first and never passes such a reference on:

- non-finite pixels (NaN, inf) in either image become 0 and are counted (``note``);
- a reference whose largest luminance is below :data:`MIN_REFERENCE_LUMINANCE` (8x the floor,
  a margin for rounding in the library's colour transforms) is *degenerate*. Against a test
  image that is degenerate too the figure is 0 (both show nothing); otherwise the exposure range
  is the one flip-evaluator derives from the test image (the only one with light to expose), and
  FLIP runs with that range given explicitly. ``note`` says which happened.

Luminance is Rec. 709 Y of the linear RGB, as in flip-evaluator's own colour transform.
"""

from __future__ import annotations

import numpy as np

MIN_REFERENCE_LUMINANCE = 1e-6
"""Below this largest luminance a reference gives flip-evaluator no exposure range (module docstring)."""
_Y = np.array([0.2126, 0.7152, 0.0722], dtype=np.float64)


def _clean(img: np.ndarray) -> tuple[np.ndarray, int]:
    img = np.asarray(img, dtype=np.float32)
    bad = ~np.isfinite(img)
    count = int(bad.any(axis=-1).sum()) if img.ndim == 3 else int(bad.sum())
    if count:
        img = np.where(bad, 0.0, img).astype(np.float32)
    return np.ascontiguousarray(np.clip(img, 0.0, None)), count


def _max_y(clean: np.ndarray) -> float:
    return float((clean[..., :3].astype(np.float64) @ _Y).max()) if clean.size else 0.0


def max_luminance(img: np.ndarray) -> float:
    """The largest Rec. 709 luminance of a linear RGB ``[H, W, 3]`` image (non-finite pixels as 0)."""
    return _max_y(_clean(img)[0])


def hdr_flip(reference: np.ndarray, test: np.ndarray, apply_magma: bool = True) -> tuple[np.ndarray, float, str | None]:
    """HDR FLIP of linear RGB ``test`` against ``reference`` (both ``[H, W, 3]``, any values):
    ``(error map, mean error, note)``. The map is magma-coloured ``[H, W, 3]`` (``apply_magma``) or
    the raw error ``[H, W, 1]`` in [0, 1]. ``note`` is None for an ordinary evaluation, else says
    what was done to a degenerate input (module docstring); the call never reaches the library
    with a reference it would exit on."""
    import flip_evaluator  # Local: an optional dependency, imported only where FLIP is computed

    ref, bad_ref = _clean(reference)
    tst, bad_test = _clean(test)
    notes = []
    if bad_ref or bad_test:
        notes.append(f"{bad_ref} reference and {bad_test} test pixels were not finite and count as black")
    params = {}
    if _max_y(ref) < MIN_REFERENCE_LUMINANCE:  # ref, tst: cleaned already
        if _max_y(tst) < MIN_REFERENCE_LUMINANCE:
            notes.append("both images are black: FLIP 0")
            shape = ref.shape[:2] + ((3,) if apply_magma else (1,))
            return np.zeros(shape, np.float32), 0.0, "; ".join(notes)
        _, _, derived = flip_evaluator.evaluate(tst, tst, "HDR", applyMagma=False, computeMeanError=False)
        params = {k: derived[k] for k in ("startExposure", "stopExposure", "numExposures")}
        notes.append("the reference is black, so the exposure range is the test image's")
    fmap, mean, _ = flip_evaluator.evaluate(ref, tst, "HDR", applyMagma=apply_magma, parameters=params)
    return fmap, float(mean), "; ".join(notes) or None
