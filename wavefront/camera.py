"""A positionable thin-lens camera (RTIOW 1, "Positionable Camera", "Defocus Blur").

Public settings with their defaults come first; everything derived from them
is computed once in :meth:`Camera.frame` for a given image size.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .sampling import random_in_unit_disk
from .vecmath import normalize

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Camera:
    """Camera settings.

    =================  ============  ===========================================
    parameter          default       meaning
    =================  ============  ===========================================
    ``look_from``      (0, 0, 0)     eye position
    ``look_at``        (0, 0, -1)    point the camera looks at
    ``vup``            (0, 1, 0)     "up" direction, must not be parallel to
                                     the view direction
    ``vfov``           90            vertical field of view, degrees (0, 180)
    ``defocus_angle``  0             cone angle of rays through each pixel,
                                     degrees; 0 is a pinhole
    ``focus_dist``     |look_at -    distance to the plane in perfect focus
                       look_from|
    =================  ============  ===========================================
    """

    look_from: Vec3 = (0.0, 0.0, 0.0)
    look_at: Vec3 = (0.0, 0.0, -1.0)
    vup: Vec3 = (0.0, 1.0, 0.0)
    vfov: float = 90.0
    defocus_angle: float = 0.0
    focus_dist: float | None = None

    def frame(self, width: int, height: int) -> CameraFrame:
        """Derived per-image state: pixel grid and lens basis."""
        center = np.asarray(self.look_from, dtype=np.float64)
        forward = np.asarray(self.look_at, dtype=np.float64) - center
        focus = float(self.focus_dist) if self.focus_dist is not None else float(np.linalg.norm(forward))
        w = -forward / np.linalg.norm(forward)
        u = np.cross(np.asarray(self.vup, dtype=np.float64), w)
        u /= np.linalg.norm(u)
        v = np.cross(w, u)
        viewport_height = 2.0 * math.tan(math.radians(self.vfov) / 2.0) * focus
        viewport_width = viewport_height * width / height
        viewport_u = viewport_width * u  # across the image, left to right
        viewport_v = -viewport_height * v  # down the image, row 0 at the top
        pixel_delta_u = viewport_u / width
        pixel_delta_v = viewport_v / height
        upper_left = center - focus * w - viewport_u / 2 - viewport_v / 2
        defocus_radius = focus * math.tan(math.radians(self.defocus_angle / 2.0))
        return CameraFrame(
            width=width,
            center=center,
            upper_left=upper_left,
            pixel_delta_u=pixel_delta_u,
            pixel_delta_v=pixel_delta_v,
            defocus_u=u * defocus_radius,
            defocus_v=v * defocus_radius,
            has_defocus=self.defocus_angle > 0,
        )


@dataclass(frozen=True)
class CameraFrame:
    width: int
    center: np.ndarray
    upper_left: np.ndarray
    pixel_delta_u: np.ndarray
    pixel_delta_v: np.ndarray
    defocus_u: np.ndarray
    defocus_v: np.ndarray
    has_defocus: bool

    def generate_rays(self, pixel: np.ndarray, u: np.ndarray):
        """Primary rays for flat pixel indices, jittered over the pixel square.

        Parameters
        ----------
        pixel : ndarray of shape (N,)
            ``row * width + column``.
        u : ndarray of shape (4, N)
            Uniforms: pixel jitter x, y and lens sample u, v.

        Returns
        -------
        origin, direction : ndarray of shape (3, N); directions are unit.
        """
        row, col = np.divmod(pixel, self.width)
        x = col + u[0]
        y = row + u[1]
        target = (
            self.upper_left[:, None]
            + self.pixel_delta_u[:, None] * x
            + self.pixel_delta_v[:, None] * y
        )
        if self.has_defocus:
            disk = random_in_unit_disk(u[2], u[3])
            origin = (
                self.center[:, None]
                + self.defocus_u[:, None] * disk[0]
                + self.defocus_v[:, None] * disk[1]
            )
        else:
            origin = np.broadcast_to(self.center[:, None], target.shape).copy()
        return origin, normalize(target - origin)
