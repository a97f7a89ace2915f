"""Read every MIP level of a four-channel texture (the latent EXRs), checked, with errors naming the file."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mtlx2neural.errors import InputError, missing_reason
from mtlx2neural.imaging.image_io import openimageio


def read_mip_chain(path) -> list[np.ndarray]:
    """Every MIP level of the RGBA texture at ``path`` as [H_j, W_j, 4] float16 arrays, finest first
    (a half EXR's stored values, exactly).

    Raises :class:`InputError` naming the file when it is missing or a folder, cannot be opened,
    has other than 4 channels, holds no image, or a level cannot be decoded (a truncated or
    corrupt file fails here, not at render time).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"latent texture {path} {missing_reason(path)}; export the material again (its latents_<k>.exr "
                         f"files hold the latent pyramid)")
    oiio = openimageio()
    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise InputError(f"latent texture {path} cannot be read: {oiio.geterror() or 'unknown format'}")
    try:
        images = []
        while inp.seek_subimage(0, len(images)):
            j = len(images)
            spec = inp.spec(0, j)
            if spec.nchannels != 4:
                raise InputError(f"latent texture {path} has {spec.nchannels} channel(s); latent textures are RGBA")
            px = inp.read_image(0, j, 0, 4, "half")  # subimage, miplevel, channel range, format
            if px is None:
                raise InputError(f"latent texture {path}: MIP level {j} cannot be decoded "
                                 f"({inp.geterror() or 'corrupt data'})")
            images.append(np.asarray(px).reshape(spec.height, spec.width, 4))
        if not images:
            raise InputError(f"latent texture {path} holds no image")
        return images
    finally:
        inp.close()
        oiio.geterror()  # clear anything left pending
