"""A pinhole renderer of semantic + planar-depth images by vectorised ray casting of the city's
boxes and vertical cylinders over the ground plane z = 0.

Per frame: primitives beyond `max_range` are culled, the rest are projected (near-plane
clipped) to their pixel rectangles, and every (pixel, primitive) pair inside those rectangles is
intersected at once in numpy, in chunks of bounded size; a z-buffer (np.minimum.at) keeps the
nearest hit. Depth is planar (along the optical axis), so it back-projects as
X = (u - cx) / fx * D with pixel centres at integer (u, v).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from sgloc.datasets.base import Frame
from sgloc.geometry import invert
from sgloc.sim.city import BOX, CYLINDER, Primitives
from sgloc.validation import MAX_COORDINATE, integer, real, setting, validate_settings

#: T_body_optical: optical (x right, y down, z forward) -> AirSim body (x forward, y right,
#: z down); a point (X, Y, Z) of the optical frame is (Z, X, Y) in the body frame.
T_BODY_OPTICAL = np.array(
    [[0.0, 0.0, 1.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)

_EDGES = np.array(
    [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]]
)


@dataclass
class Camera:
    """Pinhole camera. fx, fy, cx, cy default to Guo's proportions: fx = fy = width / 2,
    (cx, cy) = image centre (90 deg horizontal field of view). max_range (metres): nothing
    farther is drawn (the AirSim 8-bit depth format ends at 100 m)."""

    width: int = setting(320, check=integer(2, 100_000))
    height: int = setting(180, check=integer(2, 100_000))
    fx: float | None = setting(None, check=real(0.0, 1e9, low_open=True, none_ok=True))
    fy: float | None = setting(None, check=real(0.0, 1e9, low_open=True, none_ok=True))
    cx: float | None = setting(None, check=real(-1e9, 1e9, none_ok=True))
    cy: float | None = setting(None, check=real(-1e9, 1e9, none_ok=True))
    max_range: float = setting(100.0, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))
    near: float = setting(0.05, check=real(0.0, MAX_COORDINATE, low_open=True, unit="m"))

    def __post_init__(self) -> None:
        validate_settings(self, "Camera")
        self.fx = float(self.fx if self.fx is not None else self.width / 2)
        self.fy = float(self.fy if self.fy is not None else self.fx)
        self.cx = float(self.cx if self.cx is not None else self.width / 2)
        self.cy = float(self.cy if self.cy is not None else self.height / 2)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def n_pixels(self) -> int:
        return self.width * self.height

    def rays(self) -> np.ndarray:
        """(H*W,3) ray directions in the optical frame, row-major, scaled to z = 1."""
        u, v = np.meshgrid(np.arange(self.width), np.arange(self.height))
        x = (u.ravel() - self.cx) / self.fx
        y = (v.ravel() - self.cy) / self.fy
        return np.stack([x, y, np.ones_like(x)], axis=1)


@dataclass
class Rendering:
    """One rendered view: depth (H,W) planar metres (np.inf = nothing within range), semantic
    (H,W) class ids (-1 = ground or sky), instance (H,W) object ids (-1 = ground or sky)."""

    depth: np.ndarray
    semantic: np.ndarray
    instance: np.ndarray


class Renderer:
    """Ray-casts a fixed set of primitives for one camera; call `render(T_world_optical)`.

    chunk_pairs bounds the (pixel, primitive) pairs handled at once (memory ~ 200 B a pair).
    """

    def __init__(self, primitives: Primitives, camera: Camera, chunk_pairs: int = 40_000):
        self.prims = primitives
        self.camera = camera
        self.chunk_pairs = int(chunk_pairs)
        rays = camera.rays()
        self._ray_x = rays[:, 0].astype(np.float32)
        self._ray_y = rays[:, 1].astype(np.float32)
        self._corners = primitives.corners()
        self._radius = primitives.bounding_radius()
        c, s = np.cos(primitives.yaw), np.sin(primitives.yaw)
        self._cos, self._sin = c, s

    # -- culling and screen rectangles --------------------------------------------------------
    def _rectangles(self, R: np.ndarray, o: np.ndarray):
        cam = self.camera
        dist = np.linalg.norm(self.prims.center - o, axis=1) - self._radius
        idx = np.flatnonzero(dist < cam.max_range)
        C = (self._corners[idx] - o) @ R  # (m,8,3) in the optical frame
        z = C[..., 2]
        front = z >= cam.near
        any_front = front.any(axis=1)
        idx, C, z, front = idx[any_front], C[any_front], z[any_front], front[any_front]
        za, zb = z[:, _EDGES[:, 0]], z[:, _EDGES[:, 1]]
        cross = (za - cam.near) * (zb - cam.near) < 0
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(cross, (cam.near - za) / (zb - za), 0.0)
        Ca, Cb = C[:, _EDGES[:, 0]], C[:, _EDGES[:, 1]]
        P = np.concatenate([C, Ca + f[..., None] * (Cb - Ca)], axis=1)
        valid = np.concatenate([front, cross], axis=1)
        pz = np.where(valid, P[..., 2], 1.0)
        u = cam.fx * P[..., 0] / pz + cam.cx
        v = cam.fy * P[..., 1] / pz + cam.cy
        u0 = np.ceil(np.where(valid, u, np.inf).min(axis=1))
        u1 = np.floor(np.where(valid, u, -np.inf).max(axis=1))
        v0 = np.ceil(np.where(valid, v, np.inf).min(axis=1))
        v1 = np.floor(np.where(valid, v, -np.inf).max(axis=1))
        zmin = np.where(valid, P[..., 2], np.inf).min(axis=1)
        u0, v0 = np.maximum(u0, 0), np.maximum(v0, 0)
        u1, v1 = np.minimum(u1, cam.width - 1), np.minimum(v1, cam.height - 1)
        ok = (u0 <= u1) & (v0 <= v1)
        return (
            idx[ok],
            u0[ok].astype(np.int64),
            u1[ok].astype(np.int64),
            v0[ok].astype(np.int64),
            v1[ok].astype(np.int64),
            zmin[ok].astype(np.float32),
        )

    # -- ray-primitive intersections ----------------------------------------------------------
    # Both take the chunk's primitives `prim` (k,), the pair counts per primitive `cnt` (k,),
    # the camera centre `o` and the pairs' world ray directions `d` (p,3) float32 (grouped by
    # primitive, in order), and return the planar depth t of each pair's entry point (inf =
    # miss). Per-primitive terms are computed once and expanded with np.repeat.
    def _hit_boxes(self, prim: np.ndarray, cnt: np.ndarray, o: np.ndarray, d: np.ndarray):
        c, s = self._cos[prim], self._sin[prim]
        rel = o - self.prims.center[prim]
        local = np.stack(
            [c * rel[:, 0] + s * rel[:, 1], -s * rel[:, 0] + c * rel[:, 1], rel[:, 2]], 1
        )
        h = self.prims.half[prim]
        lo = np.repeat((-h - local).astype(np.float32), cnt, axis=0)
        hi = np.repeat((h - local).astype(np.float32), cnt, axis=0)
        cr = np.repeat(c.astype(np.float32), cnt)
        sr = np.repeat(s.astype(np.float32), cnt)
        dx, dy = d[:, 0], d[:, 1]
        dirs = (cr * dx + sr * dy, cr * dy - sr * dx, d[:, 2])
        tmin = tmax = None
        with np.errstate(divide="ignore", invalid="ignore"):
            for axis, dc in enumerate(dirs):
                inv = np.float32(1.0) / dc
                t1 = lo[:, axis] * inv
                t2 = hi[:, axis] * inv
                near, far = np.minimum(t1, t2), np.maximum(t1, t2)
                if tmin is None:
                    tmin, tmax = near, far
                else:
                    np.maximum(tmin, near, out=tmin)
                    np.minimum(tmax, far, out=tmax)
        return np.where((tmax >= tmin) & (tmin > 0), tmin, np.float32(np.inf))

    def _hit_cylinders(self, prim: np.ndarray, cnt: np.ndarray, o: np.ndarray, d: np.ndarray):
        ctr = self.prims.center[prim]
        r = self.prims.half[prim, 0]
        z0 = ctr[:, 2] - self.prims.half[prim, 2]
        z1 = ctr[:, 2] + self.prims.half[prim, 2]
        f32 = np.float32
        ox = np.repeat((o[0] - ctr[:, 0]).astype(f32), cnt)
        oy = np.repeat((o[1] - ctr[:, 1]).astype(f32), cnt)
        r2 = np.repeat((r * r).astype(f32), cnt)
        zlo = np.repeat((z0 - o[2]).astype(f32), cnt)  # cylinder z range relative to the camera
        zhi = np.repeat((z1 - o[2]).astype(f32), cnt)
        # the cap facing the camera: the top when the camera is above, the bottom when below
        cap_z = np.where(o[2] > z1, z1 - o[2], np.where(o[2] < z0, z0 - o[2], np.nan))
        plane = np.repeat(cap_z.astype(f32), cnt)
        dx, dy, dz = d[:, 0], d[:, 1], d[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            a = dx * dx + dy * dy
            b = ox * dx + oy * dy  # half of the usual b
            cross = dx * oy - dy * ox
            disc = a * r2 - cross * cross  # = b^2 - a (|o|^2 - r^2), without cancellation
            ts = (-b - np.sqrt(disc)) / a
            zs = ts * dz
            side = (ts > 0) & (zs >= zlo) & (zs <= zhi)
            tc = plane / dz
            px, py = ox + tc * dx, oy + tc * dy
            cap = (tc > 0) & (px * px + py * py <= r2)
        t = np.where(side, ts, f32(np.inf))
        return np.where(cap & (tc < t), tc, t)

    # -- one view -----------------------------------------------------------------------------
    def render(self, T_world_optical: np.ndarray) -> Rendering:
        """Render the view of a camera at pose T_world_optical (4x4, optical frame)."""
        T = np.asarray(T_world_optical, dtype=np.float64)
        R, o = T[:3, :3], T[:3, 3]
        # (H*W,3) world directions, optical z = 1: x R[:,0] + y R[:,1] + R[:,2] (a plain matmul
        # of an (N,3) array by 3x3 is much slower in numpy)
        Rf = R.astype(np.float32)
        dirs = self._ray_x[:, None] * Rf[:, 0] + self._ray_y[:, None] * Rf[:, 1] + Rf[:, 2]
        depth = self._ground_depth(o, dirs)
        idx, u0, u1, v0, v1, zmin = self._rectangles(R, o)
        # front to back: a pair is skipped when its pixel already holds something nearer than
        # the primitive's nearest possible point (occlusion culling across chunks)
        order = np.argsort(zmin, kind="stable")
        idx, u0, u1, v0, v1, zmin = (x[order] for x in (idx, u0, u1, v0, v1, zmin))
        w = u1 - u0 + 1
        counts = w * (v1 - v0 + 1)
        chunk_id = (np.cumsum(counts) - 1) // max(self.chunk_pairs, 1)
        starts = np.concatenate([[0], np.flatnonzero(np.diff(chunk_id)) + 1, [len(idx)]])
        hits: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for a, b in zip(starts[:-1], starts[1:], strict=True):
            if b <= a:
                continue
            hits += self._cast_chunk(
                idx[a:b], u0[a:b], v0[a:b], w[a:b], counts[a:b], zmin[a:b], o, dirs, depth
            )
        return self._labelled(depth, hits)

    def _ground_depth(self, o: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """(H*W,) float32 planar depth of the ground plane z = 0 (inf beyond max_range or with
        the camera at or below the ground); o the camera centre, dirs the world rays (z = 1)."""
        cam = self.camera
        depth = np.full(cam.n_pixels, np.inf, dtype=np.float32)
        if o[2] > 0:
            with np.errstate(divide="ignore"):
                tg = np.where(dirs[:, 2] < 0, np.float32(-o[2]) / dirs[:, 2], np.inf)
            depth = np.where(tg <= cam.max_range, tg, np.inf).astype(np.float32)
        return depth

    def _cast_chunk(
        self,
        idx: np.ndarray,
        u0: np.ndarray,
        v0: np.ndarray,
        w: np.ndarray,
        cnt: np.ndarray,
        zmin: np.ndarray,
        o: np.ndarray,
        dirs: np.ndarray,
        depth: np.ndarray,
    ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Intersect every (pixel, primitive) pair of one chunk of primitives (idx, their pixel
        rectangles' corners u0, v0, widths w, pixel counts cnt, nearest depths zmin); lower
        `depth` in place and return the hits as (pixels, depths, primitives) per primitive kind.
        """
        cam = self.camera
        kind = self.prims.kind[idx]
        local = np.repeat(np.arange(len(idx)), cnt)
        first = np.cumsum(cnt) - cnt
        k = np.arange(cnt.sum()) - first[local]
        ww = w[local]
        pix = (v0[local] + k // ww) * cam.width + u0[local] + k % ww
        visible = depth[pix] > zmin[local]
        hits = []
        for K, hit_fn in ((BOX, self._hit_boxes), (CYLINDER, self._hit_cylinders)):
            m = visible & (kind[local] == K)
            if not m.any():
                continue
            n_k = np.bincount(local[m], minlength=len(idx))
            sel = np.flatnonzero(n_k)
            p_k = pix[m]
            t = hit_fn(idx[sel], n_k[sel], o, dirs[p_k])
            hit = t < np.minimum(depth[p_k], np.float32(cam.max_range))
            p_k, t = p_k[hit], t[hit]
            np.minimum.at(depth, p_k, t)
            hits.append((p_k, t, np.repeat(idx[sel], n_k[sel])[hit]))
        return hits

    def _labelled(
        self, depth: np.ndarray, hits: list[tuple[np.ndarray, np.ndarray, np.ndarray]]
    ) -> Rendering:
        """The Rendering: final depth and, at each pixel, the class and instance of the hit
        that set it (-1 where no primitive was hit)."""
        cam = self.camera
        semantic = np.full(cam.n_pixels, -1, np.int64)
        instance = np.full(cam.n_pixels, -1, np.int64)
        if hits:
            pix = np.concatenate([h[0] for h in hits])
            t = np.concatenate([h[1] for h in hits])
            prim = np.concatenate([h[2] for h in hits])
            win = t <= depth[pix]
            semantic[pix[win]] = self.prims.label[prim[win]]
            instance[pix[win]] = self.prims.instance[prim[win]]
        shape = (cam.height, cam.width)
        return Rendering(
            depth.astype(np.float64).reshape(shape),
            semantic.reshape(shape),
            instance.reshape(shape),
        )


def render_frames(
    primitives: Primitives,
    T_world_body: np.ndarray,
    camera: Camera,
    T_world_map: np.ndarray | None = None,
    chunk_pairs: int = 40_000,
) -> Iterator[Frame]:
    """Render a robot's run frame by frame as `Frame`s (semantic, planar depth with np.inf for
    no hit, K, and T_map_sensor of the OPTICAL frame in the robot's map frame).

    T_world_body: (N,4,4) AirSim body poses (x forward, y right, z down) in the world.
    T_world_map: the robot's map frame; default its first body pose (its start frame).
    """
    poses = np.asarray(T_world_body, dtype=np.float64)
    T_map_world = invert(poses[0] if T_world_map is None else np.asarray(T_world_map))
    renderer = Renderer(primitives, camera, chunk_pairs)
    for i, T in enumerate(poses):
        T_world_optical = T @ T_BODY_OPTICAL
        r = renderer.render(T_world_optical)
        yield Frame(
            index=i,
            T_map_sensor=T_map_world @ T_world_optical,
            semantic=r.semantic,
            depth=r.depth,
            K=camera.K,
        )
