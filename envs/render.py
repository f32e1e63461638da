"""RGB-D + semantic renderer: one Open3D ``RaycastingScene`` cast per frame, then cheap numpy
lookups (per-triangle tables) for labels and colour.

Conventions:
- Poses are (4, 4) float64 world-from-camera matrices with OpenCV camera axes (x right, y down,
  z forward); the world is z-up metres (``envs.scene``).
- Intrinsics follow the OpenCV / Open3D-integrate convention: pixel (u, v) (column, row
  index) has its centre at image coordinate (u, v), so the principal point of a centred camera
  is ((W - 1) / 2, (H - 1) / 2) and a camera-frame point (X, Y, Z) projects to
  u = fx X / Z + cx, v = fy Y / Z + cy. ``RaycastingScene.create_rays_pinhole`` instead puts
  pixel centres at (u + 0.5, v + 0.5); it produces identical rays when given ``K`` with
  cx + 0.5, cy + 0.5 (see ``Camera.o3d_intrinsics``).
- Depth is z-depth (distance along the optical axis), metres, 0 where invalid.

Speed (measured as render time / bare ``cast_rays`` time, see ``eval.bench.env``): the rays
are built from per-camera precomputed direction components (a world ray direction is
separable in row and column: R[:, 0] x(u) + R[:, 1] y(v) + R[:, 2]), so a pose costs three
broadcast adds. Colour = per-triangle pre-lit albedo x a texture tile looked up from the hit
point's surface coordinates; every per-pixel step is one in-place float32 / int32 pass over
preallocated scratch buffers, split into row bands that run on worker threads (numpy
releases the GIL) when the renderer may use more than one core.

Image-textured scenes (``Scene.textured``: HM3D / MP3D meshes): a hit on a textured triangle
takes the nearest texel at its interpolated texture coordinates, times the triangle's albedo, no
extra shading (scan textures carry their lighting): ``envs.render_textures``. Untextured scenes
skip that step and render as they always have.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import open3d as o3d

from calnav.common.threads import thread_budget
from calnav.envs.render_textures import TextureSampler
from calnav.envs.scene import Scene, Texture
from calnav.envs.task import camera_pose, pinhole_intrinsics  # noqa: F401  (camera_pose re-exported: the contract owns it)

# --- lighting: a fixed directional "sun" baked per triangle (faces are flat, so n.l is a
# per-triangle constant). |n.l| so back faces (e.g. a wall seen from behind) still shade.
LIGHT_DIR = np.array([0.35, 0.6, 1.0]) / np.linalg.norm([0.35, 0.6, 1.0])
AMBIENT = 0.45          # fraction of albedo seen on surfaces facing away from the light
DIFFUSE = 0.55          # extra fraction at normal incidence (AMBIENT + DIFFUSE = 1: no clipping)

# --- procedural textures: one periodic TILE x TILE intensity tile per ``Texture`` id,
# sampled at TEXEL_M per texel in the surface's own (u, v) coordinates.
TILE = 64                        # texels per tile side (power of two: wrap with & (TILE - 1))
TEXEL_M = 0.02                   # texel size, metres (tile period 1.28 m)
_UV_OFFSET = 1024.0 * TILE       # texels added before truncation so world coords are positive
_FAR_T = 1.0e4                   # misses (t = inf) are clamped to this before texturing, metres

MAX_POST_THREADS = 2             # row bands for per-pixel work (more adds GIL hand-offs, little speed)
MIN_PIXELS_PER_BAND = 50_000     # below this a band's work (~1 ms) is not worth a thread hand-off
INVALID_ID = o3d.t.geometry.RaycastingScene.INVALID_ID
# Per-pixel buffers of a Renderer: its reusable scratch layers (name, dtype), the ray buffer
# (6 float32), Open3D's cast_rays result (t_hit, geometry and primitive ids, primitive uvs (2)
# and normals (3): 8 x 4 bytes), a frame (rgb 3 uint8, depth float32, semantic int16, instance
# int32) and the rgb noise drawn for it (3 float32).
SCRATCH_LAYERS = (("idx", np.intp), ("valid", bool), ("valid2", bool), ("tc", np.float32), ("a", np.float32),
                  ("b", np.float32), ("u", np.float32), ("texel", np.int32), ("iu", np.int32),
                  ("pattern", np.float32), ("rgba", np.uint32))
PIXEL_BYTES = (sum(np.dtype(dtype).itemsize for _, dtype in SCRATCH_LAYERS) + 6 * 4 + 8 * 4
               + 3 + 4 + 2 + 4 + 3 * 4)


def estimate_bytes(width: int, height: int) -> int:
    """Bytes a Renderer's buffers and one rendered frame take at ``width`` x ``height`` pixels."""
    return int(width) * int(height) * PIXEL_BYTES


def _texture_tiles(seed: int = 12345) -> np.ndarray:
    """(len(Texture), TILE, TILE) float32 multiplicative patterns in (0, 1], rows = v."""
    rng = np.random.default_rng(seed)
    v, u = np.mgrid[0:TILE, 0:TILE].astype(np.float64)
    two_pi = 2 * np.pi / TILE  # integer frequencies keep every pattern seamless across tiles
    tiles = np.ones((len(Texture), TILE, TILE))
    # stripes: 16 cm period (6.4 cm dark, 9.6 cm light) along the horizontal axis (wallpaper)
    tiles[Texture.STRIPES] = 0.86 + 0.14 * (np.sin(8 * two_pi * u) > 0.3)
    # checker: 32 cm tiles with 2 cm dark grout lines
    checker = ((u // 16) + (v // 16)) % 2
    tiles[Texture.CHECKER] = np.where((u % 16 == 0) | (v % 16 == 0), 0.6, 0.8 + 0.2 * checker)
    # wood grain: 16 cm planks along u, wavy grain lines, a per-plank brightness
    plank = v // 8
    wobble = 1.5 * np.sin(2 * two_pi * u + plank) + 0.7 * np.sin(5 * two_pi * u + 2 * plank)
    grain = 0.5 + 0.5 * np.sin(2 * np.pi * (v + wobble) / 2.7)
    tiles[Texture.GRAIN] = (0.78 + 0.14 * grain) * rng.uniform(0.85, 1.0, TILE // 8)[plank.astype(int)]
    tiles[Texture.GRAIN][v % 8 == 0] = 0.6
    # speckle: per-texel noise (carpet, stone)
    tiles[Texture.SPECKLE] = rng.uniform(0.72, 1.0, (TILE, TILE))
    # fabric: fine diagonal cross-hatch
    tiles[Texture.FABRIC] = np.where(((u + v) % 4 == 0) | ((u - v) % 4 == 0), 0.78, 1.0)
    return tiles.astype(np.float32)


TEXTURE_TILES: np.ndarray = _texture_tiles()


@dataclass
class Camera:
    """Pinhole camera: ``width`` x ``height`` pixels, horizontal field of view in degrees.
    Square pixels (fy = fx), principal point at the image centre."""

    width: int
    height: int
    hfov_deg: float

    def __post_init__(self) -> None:
        if self.width < 1 or self.height < 1:
            raise ValueError(f"camera resolution must be positive, got {self.width}x{self.height}")
        if not 0 < self.hfov_deg < 180:
            raise ValueError(f"camera hfov_deg must be in (0, 180), got {self.hfov_deg}")

    @classmethod
    def from_config(cls, env_cfg) -> "Camera":
        """The agent's sensor from an ``EnvConfig`` (resolution "WxH", hfov_deg)."""
        w, h = env_cfg.resolution
        return cls(width=int(w), height=int(h), hfov_deg=float(env_cfg.hfov_deg))

    @property
    def focal(self) -> float:
        """fx = fy in pixels: (W / 2) / tan(hfov / 2) (Habitat's definition)."""
        return (self.width / 2.0) / np.tan(np.deg2rad(self.hfov_deg) / 2.0)

    @property
    def intrinsics(self) -> np.ndarray:
        """(3, 3) float64 K, OpenCV pixel-centre convention (cx = (W - 1) / 2)."""
        return pinhole_intrinsics(self.width, self.height, self.hfov_deg)

    @property
    def o3d_intrinsics(self) -> np.ndarray:
        """K for ``RaycastingScene.create_rays_pinhole`` (its pixel centres are at +0.5)."""
        k = self.intrinsics
        k[0, 2] += 0.5
        k[1, 2] += 0.5
        return k


def look_at_pose(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(4, 4) float64 world-from-camera pose at ``eye`` looking at ``target`` (both (3,) metres),
    image "up" towards ``up``. Raises ValueError when looking along ``up``."""
    eye, target = np.asarray(eye, dtype=np.float64), np.asarray(target, dtype=np.float64)
    forward = target - eye
    if np.linalg.norm(forward) == 0:
        raise ValueError("look_at_pose: eye and target coincide")
    forward /= np.linalg.norm(forward)
    right = np.cross(forward, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(right) < 1e-9:
        raise ValueError("look_at_pose: viewing direction is parallel to up")
    right /= np.linalg.norm(right)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = right, np.cross(forward, right), forward, eye
    return pose


@dataclass
class RenderedView:
    """One rendered view.

    rgb: (H, W, 3) uint8. depth: (H, W) float32 z-depth in metres, 0 where invalid (miss,
    < min_depth, > max_depth). semantic: (H, W) int16 class id, -1 void / miss.
    instance: (H, W) int32 instance id, -1 none / miss. normal: (H, W, 3) float32 world-frame
    normal of the hit triangle (zeros on a miss), only when requested.
    """

    rgb: np.ndarray
    depth: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray
    normal: np.ndarray | None = None


def lit_albedo(scene: Scene) -> np.ndarray:
    """(F, 3) uint8 per-triangle albedo x calnav's directional light (``AMBIENT`` + ``DIFFUSE``
    |n . LIGHT_DIR|); unshaded for scenes whose colours carry their lighting (meta "lighting":
    "baked": shading them again would darken every surface facing away from the sun twice)."""
    v = scene.vertices.astype(np.float64)[scene.triangles]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    baked = scene.meta.get("lighting") == "baked"
    shade = np.ones(len(scene.triangles)) if baked else AMBIENT + DIFFUSE * np.abs(n @ LIGHT_DIR)
    return np.round(scene.tri_albedo * shade[:, None]).clip(0, 255).astype(np.uint8)


def build_raycasting_scene(scene: Scene) -> o3d.t.geometry.RaycastingScene:
    """A ``RaycastingScene`` holding the scene mesh as geometry 0 (primitive id = triangle index)."""
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.core.Tensor(scene.vertices), o3d.core.Tensor(scene.triangles.astype(np.uint32)))
    return rc


class Renderer:
    """Renders ``RenderedView``s of one scene with one camera. Not thread-safe (reuses buffers).

    scene: the ``Scene``; camera: the ``Camera``; min/max_depth_m: valid depth range, metres;
    rgb_noise_std: Gaussian RGB noise std in uint8 levels; depth_noise_std: Gaussian depth
    noise std in metres per metre of depth; seed: seeds the noise generator (noise is off by
    default); nthreads: threads for ``cast_rays`` and for the per-pixel post-processing
    (0 = the process's budget, ``common.threads.thread_budget``: all cores, or a worker's
    share; post-processing uses at most ``MAX_POST_THREADS`` row bands).
    ``raycasting_scene`` is public so other modules reuse it for visibility rays; pass one in
    to share it.
    """

    def __init__(self, scene: Scene, camera: Camera, min_depth_m: float = 0.5, max_depth_m: float = 5.0,
                 rgb_noise_std: float = 0.0, depth_noise_std: float = 0.0, seed: int = 0,
                 nthreads: int = 0, raycasting_scene: o3d.t.geometry.RaycastingScene | None = None):
        if not 0 <= min_depth_m < max_depth_m:
            raise ValueError(f"need 0 <= min_depth_m < max_depth_m, got {min_depth_m}, {max_depth_m}")
        if rgb_noise_std < 0 or depth_noise_std < 0:
            raise ValueError("noise standard deviations must be >= 0")
        if nthreads < 0:
            raise ValueError(f"nthreads must be >= 0 (0 = all cores), got {nthreads}")
        self.scene, self.camera = scene, camera
        self.min_depth_m, self.max_depth_m = float(min_depth_m), float(max_depth_m)
        self.rgb_noise_std, self.depth_noise_std = float(rgb_noise_std), float(depth_noise_std)
        self.nthreads = int(nthreads) or thread_budget()
        self.rng = np.random.default_rng(seed)
        self.raycasting_scene = raycasting_scene if raycasting_scene is not None else build_raycasting_scene(scene)
        self._build_tables(scene)
        self._build_buffers(camera)

    # ------------------------------------------------------------------ setup
    def _build_tables(self, scene: Scene) -> None:
        """Per-triangle lookup tables with one extra row (index F) for misses."""
        f = len(scene.triangles)
        self._n_tris = f
        self._class = np.append(scene.tri_class, np.int16(-1)).astype(np.int16)
        self._instance = np.append(scene.tri_instance, np.int32(-1)).astype(np.int32)
        lit = np.zeros((f + 1, 4), dtype=np.uint8)  # RGBA8; the miss row stays black
        lit[:f, :3] = lit_albedo(scene)
        # One uint32 per triangle: numpy's take has a fast path for 4-byte items (3-byte or
        # 12-byte rows go through a generic copy ~3x slower).
        self._lit_rgba = lit.view(np.uint32).ravel()
        tex = np.clip(scene.tri_texture.astype(np.int32), 0, len(Texture) - 1)
        self._tex_base = np.append(tex * TILE * TILE, 0).astype(np.int32)  # tile offset per triangle
        self._tiles_flat = TEXTURE_TILES.reshape(-1)
        # image textures (HM3D / MP3D meshes): untextured scenes render without this step
        self._textures = TextureSampler(scene) if scene.textured else None

    def _build_buffers(self, camera: Camera) -> None:
        """Camera-frame ray components x(u) = (u - cx) / fx, y(v) = (v - cy) / fy, z = 1 (so
        t_hit is z-depth), a reusable (H, W, 6) float32 ray buffer and per-pixel scratch."""
        k = camera.intrinsics
        self._xc = ((np.arange(camera.width) - k[0, 2]) / k[0, 0]).astype(np.float32)[None, :]  # (1, W)
        self._yc = ((np.arange(camera.height) - k[1, 2]) / k[1, 1]).astype(np.float32)[:, None]  # (H, 1)
        self._rays = np.empty((camera.height, camera.width, 6), dtype=np.float32)
        self._rays_t = o3d.core.Tensor.from_numpy(self._rays)  # shares memory with self._rays
        self._origin: np.ndarray | None = None  # origin currently in the ray buffer
        hw = (camera.height, camera.width)
        # Fresh multi-megabyte temporaries cost page faults worth ~40 % of a 640x480 cast,
        # so every intermediate lives here (rows are split between threads, never shared).
        self._scratch = {name: np.empty(hw, dtype) for name, dtype in SCRATCH_LAYERS}
        n_bands = min(MAX_POST_THREADS, self.nthreads,
                      max(1, camera.width * camera.height // MIN_PIXELS_PER_BAND))
        edges = np.linspace(0, camera.height, n_bands + 1).astype(int)
        self._bands = [slice(a, b) for a, b in zip(edges[:-1], edges[1:])]

    # ---------------------------------------------------------------- render
    def rays(self, pose: np.ndarray) -> o3d.core.Tensor:
        """Fill the ray buffer for ``pose`` ((4, 4) world-from-camera); returns the (H, W, 6)
        float32 tensor (shared with the buffer: valid until the next call)."""
        pose = np.asarray(pose, dtype=np.float64)
        if pose.shape != (4, 4):
            raise ValueError(f"pose must be a (4, 4) matrix, got shape {pose.shape}")
        r = pose[:3, :3].astype(np.float32)
        buf = self._rays
        origin = pose[:3, 3].astype(np.float32)
        if self._origin is None or not np.array_equal(origin, self._origin):  # turning in place: skip
            for k in range(3):  # column by column: 4x faster than broadcasting a (3,) vector
                buf[..., k] = origin[k]
            self._origin = origin
        for k in range(3):  # d_k(v, u) = R[k, 0] x(u) + (R[k, 1] y(v) + R[k, 2]): one broadcast add
            np.add(r[k, 0] * self._xc, r[k, 1] * self._yc + r[k, 2], out=buf[..., 3 + k])
        return self._rays_t

    def render(self, pose: np.ndarray, rng: np.random.Generator | None = None,
               normals: bool = False) -> RenderedView:
        """Render the view from ``pose`` ((4, 4) float64 world-from-camera, OpenCV axes).

        rng: noise generator for this frame (default: the renderer's own seeded one);
        normals: also return the world-frame hit normals. The returned arrays are fresh (the
        caller may keep them). Results do not depend on the thread count.
        """
        hit = self.raycasting_scene.cast_rays(self.rays(pose), nthreads=self.nthreads)
        t = hit["t_hit"].numpy()                      # (H, W) float32, inf on a miss
        prim = hit["primitive_ids"].numpy()           # (H, W) uint32, INVALID_ID on a miss
        nrm = hit["primitive_normals"].numpy()        # (H, W, 3) float32
        bary = hit["primitive_uvs"].numpy() if self._textures is not None else None   # (H, W, 2) float32
        h, w = t.shape
        frame = RenderedView(rgb=np.empty((h, w, 3), np.uint8), depth=np.empty((h, w), np.float32),
                      semantic=np.empty((h, w), np.int16), instance=np.empty((h, w), np.int32))
        rng = self.rng if rng is None else rng
        rgb_noise = None
        if self.rgb_noise_std > 0:  # drawn up front (planar) so bands never touch the generator
            rgb_noise = rng.standard_normal((3, h, w), dtype=np.float32)
            rgb_noise *= np.float32(self.rgb_noise_std)

        def work(rows: slice) -> None:
            self._post(rows, t, prim, nrm, frame, rgb_noise, bary)

        if len(self._bands) == 1:
            work(self._bands[0])
        else:  # numpy releases the GIL in these loops: bands run truly in parallel
            futures = [_pool().submit(work, rows) for rows in self._bands[1:]]
            work(self._bands[0])
            for fut in futures:
                fut.result()

        if self.depth_noise_std > 0:  # multiplicative: std grows linearly with depth
            d = frame.depth
            d *= 1 + np.float32(self.depth_noise_std) * rng.standard_normal(d.shape, dtype=np.float32)
            d[(d < self.min_depth_m) | (d > self.max_depth_m)] = 0.0
        if normals:
            frame.normal = np.where((prim != INVALID_ID)[..., None], nrm, np.float32(0.0))
        return frame

    def _post(self, rows: slice, t: np.ndarray, prim: np.ndarray, nrm: np.ndarray, frame: RenderedView,
              rgb_noise: np.ndarray | None, bary: np.ndarray | None = None) -> None:
        """Per-pixel work for image rows ``rows``: depth, labels and colour into ``frame``."""
        s = {k: v[rows] for k, v in self._scratch.items()}
        t, prim, nrm, buf = t[rows], prim[rows], nrm[rows], self._rays[rows]
        f32 = np.float32
        idx = np.minimum(prim, self._n_tris, out=s["idx"])  # misses -> the extra table row
        valid = np.greater_equal(t, self.min_depth_m, out=s["valid"])
        valid &= np.less_equal(t, self.max_depth_m, out=s["valid2"])  # inf fails this test
        np.copyto(frame.depth[rows], t)
        np.logical_not(valid, out=valid)
        np.putmask(frame.depth[rows], valid, f32(0.0))
        self._class.take(idx, out=frame.semantic[rows])
        self._instance.take(idx, out=frame.instance[rows])

        # Texture coordinates from the hit point p = o + t d projected on the surface:
        # u = (nz - ny) px + nx py, v = pz + nz py. On a vertical wall (nz = 0) that is the
        # horizontal coordinate along the wall and the height; on a floor or ceiling
        # (nz = +-1) it is (+-x, +-y + const): every axis-aligned surface gets an undistorted
        # 2D pattern, and the pattern is fixed to the world (no swimming as the camera moves).
        tc = np.minimum(t, f32(_FAR_T), out=s["tc"])  # finite everywhere (misses are black anyway)
        nx, ny, nz = nrm[..., 0], nrm[..., 1], nrm[..., 2]
        a, b = s["a"], s["b"]
        np.multiply(tc, buf[..., 3], out=a)
        a += buf[..., 0]                                   # a = px
        np.subtract(nz, ny, out=b)
        a *= b                                             # a = (nz - ny) px
        np.multiply(tc, buf[..., 4], out=b)
        b += buf[..., 1]                                   # b = py
        u = np.multiply(b, nx, out=s["u"])
        u += a                                             # u done
        b *= nz                                            # b = nz py
        np.multiply(tc, buf[..., 5], out=a)
        a += buf[..., 2]
        a += b                                             # a = v
        inv, off, mask = f32(1.0 / TEXEL_M), f32(_UV_OFFSET), TILE - 1
        for arr in (u, a):  # to positive texel units so truncation is floor
            arr *= inv
            arr += off
        texel, iu = s["texel"], s["iu"]
        np.copyto(texel, a, casting="unsafe")
        texel &= mask
        texel *= TILE
        np.copyto(iu, u, casting="unsafe")
        iu &= mask
        texel += iu
        texel += self._tex_base.take(idx, out=iu)
        pattern = self._tiles_flat.take(texel, out=s["pattern"])

        # colour = pre-lit albedo (RGBA8 gathered as one uint32) x pattern, channel by channel
        rgba = self._lit_rgba.take(idx, out=s["rgba"]).view(np.uint8).reshape(*t.shape, 4)
        if bary is not None:
            self._textures.apply(rgba, idx, bary[rows])
        out = frame.rgb[rows]
        for c in range(3):
            np.multiply(rgba[..., c], pattern, out=a)
            if rgb_noise is not None:
                a += rgb_noise[c, rows]
                np.clip(a, 0, 255, out=a)
            np.copyto(out[..., c], a, casting="unsafe")



_POOL: ThreadPoolExecutor | None = None
_POOL_PID: int | None = None


def _pool() -> ThreadPoolExecutor:
    """Process-wide worker threads for row bands (created on first use, shared by renderers).
    Re-created in a forked child: the parent's worker threads do not exist there."""
    global _POOL, _POOL_PID
    if _POOL is None or _POOL_PID != os.getpid():
        _POOL = ThreadPoolExecutor(max_workers=MAX_POST_THREADS - 1, thread_name_prefix="calnav-render")
        _POOL_PID = os.getpid()
    return _POOL
