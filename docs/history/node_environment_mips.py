# ruff: noqa  (an archived measurement script, run as written from /work/main)
import sys; sys.path.insert(0, "/work/main")
import numpy as np

from mtlx2neural.render.lighting import EnvironmentMap

img = EnvironmentMap.sky(128, 256).image.numpy().astype(np.float64)
H, W = img.shape[:2]
th = (np.arange(H) + 0.5) / H * np.pi
w = np.sin(th)[:, None, None]
# irradiance onto an upward normal (y up in the sky's frame): cos = cos(theta)
up = np.clip(np.cos(th), 0, None)[:, None, None]
ref_all = (img * w).sum((0, 1)); ref_up = (img * w * up).sum((0, 1))
lv = img
for k in range(8):
    f = np.repeat(np.repeat(lv, 2 ** k, 0), 2 ** k, 1)
    print(f"level {k} ({lv.shape[1]}x{lv.shape[0]}): sphere integral ratio {np.round((f*w).sum((0,1))/ref_all,3)}  "
          f"up-facing irradiance ratio {np.round((f*w*up).sum((0,1))/ref_up,3)}")
    lv = lv.reshape(lv.shape[0] // 2, 2, lv.shape[1] // 2, 2, 3).mean((1, 3))
