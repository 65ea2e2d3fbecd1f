"""How image pixels map onto the array: a scale and an offset per axis.

A pipeline that maps a camera frame onto the array by one rule records that rule
in ``Pattern.params["to_array"]`` (:meth:`ImageToArray.as_params`), so that what
the array shows can be drawn over the camera image (the live preview) and an
object's position in the image compared with where the array put it (tracking
error, ``bench/live.py``). Coordinates are (row, col); pixel centres and
actuator centres are whole numbers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ImageToArray:
    """``array_row = row_scale * image_row + row0``, and likewise for columns."""

    row_scale: float
    row0: float
    col_scale: float
    col0: float

    @classmethod
    def fit_frame(cls, height: int, width: int, rows: int, cols: int, *,
                  margin: float = 0.0) -> ImageToArray:
        """The whole frame fitted into the array keeping its aspect ratio, centred: one
        cell spans ``max(width / cols, height / rows)`` pixels (seed 000 eq. 11's rule,
        applied to the camera's frame rather than to the object), and each actuator sits
        at the centre of its cell."""
        px = max(width / max(cols - 2 * margin, 1e-9), height / max(rows - 2 * margin, 1e-9))
        s = 1.0 / px
        return cls(s, (0.5 - height / 2.0) * s + rows / 2.0 - 0.5,
                   s, (0.5 - width / 2.0) * s + cols / 2.0 - 0.5)

    @classmethod
    def from_params(cls, params: dict) -> ImageToArray | None:
        m = params.get("to_array") if params else None
        if not m:
            return None
        return cls(float(m["row"][0]), float(m["row"][1]), float(m["col"][0]),
                   float(m["col"][1]))

    def as_params(self) -> dict:
        return {"row": [round(self.row_scale, 9), round(self.row0, 9)],
                "col": [round(self.col_scale, 9), round(self.col0, 9)]}

    def to_array(self, points: np.ndarray) -> np.ndarray:
        """(n, 2) image (row, col) -> array (row, col)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return np.stack([p[:, 0] * self.row_scale + self.row0,
                         p[:, 1] * self.col_scale + self.col0], axis=1)

    def to_image(self, points: np.ndarray) -> np.ndarray:
        """(n, 2) array (row, col) -> image (row, col)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        return np.stack([(p[:, 0] - self.row0) / self.row_scale,
                         (p[:, 1] - self.col0) / self.col_scale], axis=1)
