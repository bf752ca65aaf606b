"""A pinhole or orthographic camera as Blender describes one (the splat renderers' and the
scattering views' camera alike).

The camera looks along its own -z with +y up (Blender's and OpenGL's
convention).  Image pixel ``(row, col)`` has its centre at
``x = col + 0.5`` (rightward), ``y = row + 0.5`` (downward), row 0 at the top.
``fov`` is the *horizontal* angle of view (Blender's ``camera.data.angle``
with sensor fit ``'HORIZONTAL'``, or ``'AUTO'`` when width >= height);
an orthographic camera shows ``ortho_scale`` scene units across the width
(Blender's ``ortho_scale`` with the same fit).  So for a ``width``-pixel image
a camera-space point ``(X, Y, Z)`` lands at

* perspective: ``x = W/2 + f X/(-Z)``, ``y = H/2 - f Y/(-Z)``, ``f = (W/2)/tan(fov/2)``;
* orthographic: ``x = W/2 + X W/ortho_scale``, ``y = H/2 - Y W/ortho_scale``.
"""

from dataclasses import dataclass

import numpy as np

from ..errors import DataError


@dataclass(frozen=True, eq=False)
class Camera:
    """World-to-camera transform and lens.

    Parameters
    ----------
    world_to_camera : (4, 4) array
        Rigid transform from scene to camera coordinates (the inverse of a
        Blender camera's ``matrix_world``).
    fov : float
        Horizontal angle of view in degrees (perspective).
    orthographic : bool
    ortho_scale : float
        Scene units across the image width (orthographic).
    width, height : int
        Image size in pixels of the views that take it from the camera (the scattering
        views, :func:`..light.scatter.render`); the splat renderers are given theirs.
    """

    world_to_camera: np.ndarray
    fov: float = 40.0
    orthographic: bool = False
    ortho_scale: float = 2.0
    width: int = 128
    height: int = 96

    def __post_init__(self):
        m = np.asarray(self.world_to_camera, dtype=np.float64)
        if m.shape != (4, 4) or not np.all(np.isfinite(m)):
            raise DataError(f"must be a finite 4x4 matrix, got shape {m.shape}", field="camera")
        r = m[:3, :3]
        if not np.allclose(r @ r.T, np.eye(3), atol=1e-6) or np.linalg.det(r) < 0:
            raise DataError("world_to_camera must be a rotation plus translation (no scale or mirror)", field="camera")
        if self.orthographic:
            if not (np.isfinite(self.ortho_scale) and self.ortho_scale > 0):
                raise DataError(f"ortho_scale must be positive, got {self.ortho_scale!r}", field="camera")
        elif not (np.isfinite(self.fov) and 0 < self.fov < 180):
            raise DataError(f"fov must be in (0, 180) degrees, got {self.fov!r}", field="camera")
        if int(self.width) < 1 or int(self.height) < 1:
            raise DataError(f"image size must be positive, got {self.width}x{self.height}", field="camera")
        object.__setattr__(self, "world_to_camera", m)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def look_at(cls, position, target, up=(0.0, 0.0, 1.0), fov=40.0, orthographic=False, ortho_scale=2.0,
                width=128, height=96):
        """A camera at ``position`` looking at ``target`` with ``up`` projected to the image's up."""
        eye = np.asarray(position, dtype=np.float64)
        fwd = np.asarray(target, dtype=np.float64) - eye
        if not np.linalg.norm(fwd) > 0:
            raise DataError("position and target coincide", field="camera")
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, np.asarray(up, dtype=np.float64))
        if not np.linalg.norm(right) > 1e-9:
            raise DataError("up is parallel to the view direction", field="camera")
        right /= np.linalg.norm(right)
        true_up = np.cross(right, fwd)
        rot = np.stack([right, true_up, -fwd])  # rows: camera x, y, z in world coordinates
        m = np.eye(4)
        m[:3, :3] = rot
        m[:3, 3] = -rot @ eye
        cam = cls(m, float(fov), bool(orthographic), float(ortho_scale), width, height)
        object.__setattr__(cam, "_eye", eye.copy())  # as given: the matrix's inverse loses its last bits
        return cam

    @property
    def position(self):
        """Eye position in scene coordinates."""
        eye = getattr(self, "_eye", None)
        if eye is not None:
            return eye.copy()
        r = self.world_to_camera[:3, :3]
        return -r.T @ self.world_to_camera[:3, 3]

    def basis(self):
        """(forward, right, up) unit vectors in scene coordinates (the view looks along forward)."""
        r = self.world_to_camera[:3, :3]
        return -r[2], r[0].copy(), r[1].copy()

    def rays(self):
        """Unit ray directions (height, width, 3) of a perspective camera through the pixel
        centres, row 0 at the top of the image."""
        if self.orthographic:
            raise DataError("an orthographic camera has no rays from one eye", field="camera")
        f, r, u = self.basis()
        t = np.tan(0.5 * np.deg2rad(self.fov))
        xs = ((np.arange(self.width) + 0.5) / self.width * 2.0 - 1.0) * t
        ys = (1.0 - (np.arange(self.height) + 0.5) / self.height * 2.0) * t * self.height / self.width
        d = f[None, None] + xs[None, :, None] * r[None, None] + ys[:, None, None] * u[None, None]
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def to_camera(self, xyz):
        """Scene points ``(n, 3)`` in camera coordinates."""
        m = self.world_to_camera
        return np.asarray(xyz, dtype=np.float64).reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]

    def pixels_per_unit(self, width):
        """``f`` (perspective focal length in pixels) or pixels per scene unit (orthographic)."""
        if self.orthographic:
            return width / self.ortho_scale
        return 0.5 * width / np.tan(np.deg2rad(self.fov) / 2.0)

    def project(self, xyz, width, height):
        """Pixel coordinates ``(n, 2)`` (x right, y down) and depth ``-Z`` of scene points."""
        c = self.to_camera(xyz)
        f = self.pixels_per_unit(width)
        depth = -c[:, 2]
        if self.orthographic:
            s = np.ones_like(depth)
        else:
            with np.errstate(divide="ignore", invalid="ignore"):
                s = 1.0 / depth
        return np.column_stack([0.5 * width + f * c[:, 0] * s, 0.5 * height - f * c[:, 1] * s]), depth


__all__ = ["Camera"]
