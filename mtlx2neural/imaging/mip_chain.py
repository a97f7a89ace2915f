"""Read every MIP level of a four-channel texture (the latent EXRs), checked, with errors naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mtlx2neural.errors import InputError, missing_reason
from mtlx2neural.imaging.image_io import openimageio


def read_mip_chain(path, channels: int = 4, what: str = "latent texture") -> list[np.ndarray]:
    """Every MIP level of the ``channels``-channel texture at ``path`` (RGBA by default) as
    [H_j, W_j, channels] float16 arrays, finest first (a half EXR's stored values, exactly); ``what``
    names the file in errors.

    Raises :class:`InputError` naming the file when it is missing or a folder, cannot be opened,
    has other than ``channels`` channels, holds no image, or a level cannot be decoded (a truncated or
    corrupt file fails here, not at render time).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} {path} {missing_reason(path)}; export the material again"
                         + (" (its latents_<k>.exr files hold the latent pyramid)" if what == "latent texture" else ""))
    oiio = openimageio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"{what} {path} cannot be read: {oiio.geterror() or 'unknown format'}")
    try:
        images = []
        while inp.seek_subimage(0, len(images)):
            j = len(images)
            spec = inp.spec(0, j)
            if spec.nchannels != channels:
                raise InputError(f"{what} {path} has {spec.nchannels} channel(s); it should have {channels}")
            px = inp.read_image(0, j, 0, channels, "half")  # subimage, miplevel, channel range, format
            if px is None:
                raise InputError(f"{what} {path}: MIP level {j} cannot be decoded "
                                 f"({inp.geterror() or 'corrupt data'})")
            images.append(np.asarray(px).reshape(spec.height, spec.width, channels))
        if not images:
            raise InputError(f"{what} {path} holds no image")
        return images
    finally:
        inp.close()
        oiio.geterror()  # clear anything left pending
