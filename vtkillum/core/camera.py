"""A camera equivalent to ``vtkCamera`` (perspective and parallel projection).

Pixel ``(row, col)`` of an ``H x W`` image looks through the normalised device
coordinates ``x = 2 (col + 0.5) / W - 1`` and ``y = 1 - 2 (row + 0.5) / H``:
row 0 is the top of the picture, as in a PNG. ``view_angle`` is VTK's vertical
view angle in degrees; ``parallel_scale`` is half the height of the view in world
units, as in VTK.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Camera:
    """Pinhole or parallel camera.

    Parameters
    ----------
    position, focal_point, view_up : (3,) float
        As ``vtkCamera``; ``view_up`` is orthogonalised against the view direction.
    view_angle : float
        Vertical field of view in degrees (perspective projection).
    parallel_projection : bool
        Use an orthographic projection of half-height ``parallel_scale``.
    parallel_scale : float
        Half the view height in world units (parallel projection only).
    """

    position: np.ndarray = (0.0, 0.0, 5.0)
    focal_point: np.ndarray = (0.0, 0.0, 0.0)
    view_up: np.ndarray = (0.0, 1.0, 0.0)
    view_angle: float = 30.0
    parallel_projection: bool = False
    parallel_scale: float = 1.0

    def __post_init__(self) -> None:
        for name in ("position", "focal_point", "view_up"):
            v = np.asarray(getattr(self, name), dtype=np.float64).reshape(-1)
            if v.shape != (3,) or not np.all(np.isfinite(v)):
                raise ValueError(f"camera.{name} must be three finite numbers")
            setattr(self, name, v)
        if np.linalg.norm(self.focal_point - self.position) == 0:
            raise ValueError("camera.position and camera.focal_point must differ")
        if not (0 < float(self.view_angle) < 180):
            raise ValueError("camera.view_angle must lie in (0, 180) degrees")
        if not (np.isfinite(self.parallel_scale) and self.parallel_scale > 0):
            raise ValueError("camera.parallel_scale must be positive")
        f = self.forward
        if np.linalg.norm(np.cross(f, self.view_up)) < 1e-9:
            raise ValueError("camera.view_up must not be parallel to the view direction")
        self.view_angle = float(self.view_angle)
        self.parallel_scale = float(self.parallel_scale)
        self.parallel_projection = bool(self.parallel_projection)

    @property
    def forward(self) -> np.ndarray:
        """Unit view direction (position towards focal point)."""
        d = self.focal_point - self.position
        return d / np.linalg.norm(d)

    def basis(self):
        """Orthonormal ``(right, up, forward)`` as VTK's view transform builds it."""
        f = self.forward
        r = np.cross(f, self.view_up)
        r /= np.linalg.norm(r)
        u = np.cross(r, f)
        return r, u, f

    def ray_directions(self, width: int, height: int):
        """Ray origins and unit directions, each ``(height, width, 3)``, for testing and numpy use."""
        r, u, f = self.basis()
        cols = (np.arange(width) + 0.5) / width * 2 - 1
        rows = 1 - (np.arange(height) + 0.5) / height * 2
        x, y = np.meshgrid(cols, rows)
        aspect = width / height
        if self.parallel_projection:
            s = self.parallel_scale
            origins = (self.position + (x * aspect * s)[..., None] * r + (y * s)[..., None] * u)
            dirs = np.broadcast_to(f, origins.shape).copy()
        else:
            t = np.tan(np.radians(self.view_angle) / 2)
            dirs = f + (x * aspect * t)[..., None] * r + (y * t)[..., None] * u
            dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
            origins = np.broadcast_to(self.position, dirs.shape).copy()
        return origins, dirs

    def image_plane(self, width: int, height: int):
        """Where the picture of ``width`` x ``height`` pixels lies in the world, facing the camera.

        The plane through the focal point perpendicular to the view direction, cut to the
        view frustum (height ``2 d tan(view_angle / 2)`` at focal distance ``d``, or ``2
        parallel_scale``), holds the pixels' centres exactly where
        :meth:`ray_directions` sends their rays through it. Returns ``(origin, spacing,
        direction)`` of a VTK image of the picture (pixel ``(0, 0)`` at the bottom left,
        as VTK shows images): origin (3,) the centre of that pixel, spacing (3,) (square
        pixels; the third entry 1), direction (3, 3) whose columns are the camera's
        right, up and backward (towards the camera) unit vectors.
        """
        r, u, f = self.basis()
        if self.parallel_projection:
            half_height = self.parallel_scale
        else:
            distance = np.linalg.norm(self.focal_point - self.position)
            half_height = distance * np.tan(np.radians(self.view_angle) / 2)
        pixel = 2.0 * half_height / height
        origin = (self.focal_point + (-0.5 * width + 0.5) * pixel * r
                  + (-0.5 * height + 0.5) * pixel * u)
        return origin, np.array([pixel, pixel, 1.0]), np.stack([r, u, -f], axis=1)

    def to_dict(self) -> dict:
        d = {"position": self.position.tolist(), "focal_point": self.focal_point.tolist(),
             "view_up": self.view_up.tolist()}
        if self.parallel_projection:
            d["parallel_scale"] = self.parallel_scale
        else:
            d["view_angle"] = self.view_angle
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "Camera":
        """Build from the scene file's ``camera`` object (``parallel_scale`` selects parallel)."""
        if not isinstance(d, dict):
            raise ValueError("camera must be an object")
        unknown = set(d) - {"position", "focal_point", "view_up", "view_angle", "parallel_scale"}
        if unknown:
            raise ValueError(f"camera: unknown field(s) {sorted(unknown)}")
        if "view_angle" in d and "parallel_scale" in d:
            raise ValueError("camera: give either view_angle (perspective) or parallel_scale")
        kw = {k: d[k] for k in ("position", "focal_point", "view_up", "view_angle") if k in d}
        if "parallel_scale" in d:
            kw.update(parallel_projection=True, parallel_scale=d["parallel_scale"])
        try:
            return cls(**kw)
        except (TypeError, ValueError) as err:
            raise ValueError(str(err) if str(err).startswith("camera") else f"camera: {err}") from err

    @classmethod
    def looking_at_bounds(cls, bounds, direction=(0.0, 0.0, -1.0), view_up=(0.0, 1.0, 0.0),
                          view_angle: float = 30.0) -> "Camera":
        """Frame an axis-aligned box as ``vtkRenderer.ResetCamera`` does.

        Parameters
        ----------
        bounds : (6,) float
            ``(xmin, xmax, ymin, ymax, zmin, zmax)`` in world units.
        direction : (3,) float
            View direction (from the camera towards the box centre).
        """
        b = np.asarray(bounds, dtype=np.float64).reshape(3, 2)
        centre = b.mean(axis=1)
        radius = 0.5 * np.linalg.norm(b[:, 1] - b[:, 0])
        radius = radius if radius > 0 else 0.5
        d = np.asarray(direction, dtype=np.float64)
        d /= np.linalg.norm(d)
        distance = radius / np.sin(np.radians(view_angle) / 2)
        return cls(centre - distance * d, centre, view_up, view_angle)
