"""Create latent EXRs and a procedural HDR environment (radiance + irradiance) with OIIO."""
import numpy as np, OpenImageIO as oiio, os
D = os.path.dirname(os.path.abspath(__file__))

def write(path, arr):
    h, w, c = arr.shape
    out = oiio.ImageOutput.create(path)
    out.open(path, oiio.ImageSpec(w, h, c, oiio.FLOAT))
    out.write_image(arr.astype(np.float32)); out.close()

# latent_const.exr: constant latent (rgb = albedo 0.8,0.5,0.25; w = 0)
write(f"{D}/latent_const.exr", np.broadcast_to(np.array([0.8, 0.5, 0.25, 0.0], np.float32), (64, 64, 4)).copy())
# latent_checker.exr: 8x8 checker, 256x256, for the explicit-LOD demo
y, x = np.mgrid[0:256, 0:256]
chk = (((x // 32) + (y // 32)) % 2).astype(np.float32)[..., None]
a = np.array([0.9, 0.1, 0.1, 0.0], np.float32); b = np.array([0.1, 0.3, 0.9, 0.0], np.float32)
write(f"{D}/latent_checker.exr", chk * a + (1 - chk) * b)

# Procedural lat-long environment 512x256 using MaterialX's convention:
# u = atan(x, -z)/(2pi)+0.5, v = -asin(y)/pi + 0.5  (v=0 is up).
W, H = 512, 256
v, u = (np.mgrid[0:H, 0:W] + 0.5) / np.array([H, W])[:, None, None]
lat = (0.5 - v) * np.pi; lon = (u - 0.5) * 2 * np.pi
d = np.stack([np.cos(lat) * np.sin(lon), np.sin(lat), -np.cos(lat) * np.cos(lon)], -1)
sky = np.where(d[..., 1:2] > 0, np.array([0.4, 0.6, 1.0]) * (0.5 + d[..., 1:2]), np.array([0.25, 0.2, 0.15]))
sun_dir = np.array([0.5, 0.6, 0.62]); sun_dir /= np.linalg.norm(sun_dir)
sky = sky + np.array([8.0, 7.0, 5.0]) * (np.clip(d @ sun_dir, 0, 1) ** 64)[..., None]
write(f"{D}/env_radiance.hdr", sky)

# Cosine-convolved irradiance (divided by pi, MaterialX convention: Lambert albedo * E/pi)
h2, w2 = 32, 64
v2, u2 = (np.mgrid[0:h2, 0:w2] + 0.5) / np.array([h2, w2])[:, None, None]
lat2 = (0.5 - v2) * np.pi; lon2 = (u2 - 0.5) * 2 * np.pi
n = np.stack([np.cos(lat2) * np.sin(lon2), np.sin(lat2), -np.cos(lat2) * np.cos(lon2)], -1).reshape(-1, 3)
# convolve against a 4x box-downsampled copy to keep memory small (~130 MB)
f = 4
skyd = sky.reshape(H // f, f, W // f, f, 3).mean((1, 3)).reshape(-1, 3)
latd = lat.reshape(H // f, f, W // f, f).mean((1, 3)); lond = lon.reshape(H // f, f, W // f, f).mean((1, 3))
dd = np.stack([np.cos(latd) * np.sin(lond), np.sin(latd), -np.cos(latd) * np.cos(lond)], -1).reshape(-1, 3)
dw = (np.cos(latd) * (np.pi * f / H) * (2 * np.pi * f / W)).reshape(-1)
cosw = np.clip(n @ dd.T, 0, None) * dw[None]
irr = (cosw @ skyd) / np.pi
write(f"{D}/env_irradiance.hdr", irr.reshape(h2, w2, 3))
print("assets written")
