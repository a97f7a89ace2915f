"""Mean absolute pixel differences (8-bit) against the oren_nayar reference + contact sheet."""
import numpy as np, OpenImageIO as oiio, os
os.chdir(os.path.join(os.path.dirname(os.path.abspath(__file__)), "out"))
L = lambda f: np.load(f + ".npy")[..., :3].astype(float)
for ref, f in [("ref", "neural_env0"), ("ref", "neural_env1"), ("ref_nodirect", "neural_env1_nodirect")]:
    d = np.abs(L(f) - L(ref))
    print(f"{f:24s} vs {ref:14s}: mean|diff| {d.mean():.4f}  max {d.max():.0f}  (0..255)")
imgs = [np.load(f + ".npy")[..., :3] for f in ["ref", "neural_env0", "neural_env1", "neural_checker_lod4"]]
s = np.ascontiguousarray(np.flipud(np.concatenate(imgs, 1)))
o = oiio.ImageOutput.create("sheet.png"); o.open("sheet.png", oiio.ImageSpec(s.shape[1], s.shape[0], 3, oiio.UINT8)); o.write_image(s); o.close()
