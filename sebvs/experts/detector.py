"""Colour-cube detector on RGB images (the paper's YOLOv8, replaced by OpenCV).

The targets in our scenes are flat-coloured cubes on grey/green/checker backgrounds, so
hue + saturation segmentation finds them exactly; connected components give every blob's
area, bounding box and centroid, and a contour's minimum-area rectangle its in-image
rotation (the arm expert aligns the gripper's yaw with it).

Pixel conventions (the same as the scenes' projected truth): continuous image coordinates
with (0, 0) the top-left corner of the top-left pixel, u to the right, v down; pixel (i, j)
covers [i, i+1] x [j, j+1], so its centre is (i + 0.5, j + 0.5). A blob spanning columns
i0..i1 has bbox x = i0, w = i1 - i0 + 1 (u from x to x + w).

The colour is a parameter: `ColorDetector(rgb=(0.9, 0.15, 0.1))` (the nav cube's rgba), with
a hue tolerance in degrees. Brightness is not bounded, since lighting conditions (low light,
flicker) scale value but hardly hue or saturation: in the nav scene's low light the cube
renders as about (9, 2, 1) DN. What guards against grey pixels is the chroma (max - min of
R, G, B) in DN: near black, quantisation alone makes a grey pixel like (5, 3, 3) look
40 % saturated and red, but its chroma is only 2 DN.
"""
from __future__ import annotations

import colorsys
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

# The nav scene's target cube colour (sebvs/sim/nav.py: rgba 0.9 0.15 0.1).
NAV_TARGET_RGB = (0.9, 0.15, 0.1)


@dataclass
class Detection:
    """One blob of the target colour.

    centroid  (u, v) px, mean of the blob's pixel centres
    bbox      (x, y, w, h) px, x/y of the top-left corner, w/h in whole pixels
    area      pixels in the blob
    confidence in [0, 1]: how box-like and how large the blob is (1 for a solid blob of at
              least `full_area` px)
    angle     deg in [0, 90): rotation of the blob's minimum-area rectangle (a square's
              orientation, folded into its 90 deg symmetry)
    """
    centroid: tuple[float, float]
    bbox: tuple[int, int, int, int]
    area: int
    confidence: float
    angle: float = 0.0

    @property
    def width(self) -> int:
        return self.bbox[2]

    def as_dict(self) -> dict:
        """msgpack-able form (for message meta)."""
        d = asdict(self)
        d["centroid"] = [float(c) for c in self.centroid]
        d["bbox"] = [int(b) for b in self.bbox]
        return d


@dataclass
class ColorDetector:
    """Finds blobs of one colour.

    rgb       target colour, floats in [0, 1] (as in the MJCF rgba)
    hue_tol   deg: accepted hue distance from the target's hue (wraps at 360)
    s_min     minimum saturation, 0..255 (background greys sit far below)
    c_min     minimum chroma, DN: max(R, G, B) - min(R, G, B) (see the module docstring)
    min_area  px: smaller blobs are noise
    full_area px: the area from which the size part of the confidence is 1
    open_px   morphological opening kernel (px, 0 = none); removes speckle, but also
              erases targets a few pixels across, so off by default
    """
    rgb: tuple[float, float, float] = NAV_TARGET_RGB
    hue_tol: float = 15.0
    s_min: int = 90
    c_min: int = 5
    min_area: int = 3
    full_area: int = 25
    open_px: int = 0
    _ranges: list = field(default_factory=list, init=False, repr=False)

    def __post_init__(self) -> None:
        h, s, v = colorsys.rgb_to_hsv(*[float(c) for c in self.rgb])
        if s < 0.3:
            raise ValueError(f"detector: colour {self.rgb} is too grey to segment by hue")
        # OpenCV 8-bit hue is degrees / 2, in [0, 180)
        hc, tol = h * 180.0, self.hue_tol / 2.0
        lo, hi = hc - tol, hc + tol
        lo_s, lo_v = int(self.s_min), int(self.c_min)   # value >= chroma, a cheap pre-cut
        spans = [(lo, hi)]
        if lo < 0:
            spans = [(0, hi), (180 + lo, 179.999)]
        elif hi >= 180:
            spans = [(lo, 179.999), (0, hi - 180)]
        self._ranges = [(np.array([int(np.ceil(a)), lo_s, lo_v], np.uint8),
                         np.array([int(np.floor(b)), 255, 255], np.uint8)) for a, b in spans]

    def mask(self, rgb: np.ndarray) -> np.ndarray:
        """(H, W) uint8 mask, 255 where the pixel has the target colour."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ValueError(f"detector wants (H, W, 3) uint8 RGB, got {rgb.shape} {rgb.dtype}")
        hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV)
        m = cv2.inRange(hsv, *self._ranges[0])
        for lo, hi in self._ranges[1:]:
            m |= cv2.inRange(hsv, lo, hi)
        # chroma test only inside the box around what the hue test passed (usually the
        # cube alone): cv2 ops on a small ROI instead of numpy over the whole frame
        x, y, w, h = cv2.boundingRect(m)
        if w:
            roi = rgb[y:y + h, x:x + w]
            r, g, b = cv2.split(roi)
            chroma = cv2.subtract(cv2.max(cv2.max(r, g), b), cv2.min(cv2.min(r, g), b))
            # numpy, not cv2.compare: OpenCV reads a 1 x 1 array as a scalar and refuses
            # "scalar op scalar", which a single pixel passing the hue test gives
            m[y:y + h, x:x + w] &= np.where(chroma >= self.c_min, 255, 0).astype(np.uint8)
        if self.open_px > 1:
            k = np.ones((self.open_px, self.open_px), np.uint8)
            m = cv2.morphologyEx(m, cv2.MORPH_OPEN, k)
        return m

    def detect_all(self, rgb: np.ndarray) -> list[Detection]:
        """Every blob of at least min_area px, largest first."""
        m = self.mask(rgb)
        # components inside the mask's bounding box only: cheaper than the whole frame
        bx, by, bw, bh = cv2.boundingRect(m)
        if bw == 0:
            return []
        n, labels, stats, cents = cv2.connectedComponentsWithStats(
            m[by:by + bh, bx:bx + bw], connectivity=8)
        out = []
        for i in range(1, n):
            x, y, w, h, area = (int(v) for v in stats[i])
            if area < self.min_area:
                continue
            fill = area / float(w * h)
            size = min(1.0, area / float(self.full_area))
            # a square seen at an angle fills >= 1/2 of its box; a thin streak much less
            conf = size * min(1.0, fill / 0.5)
            angle = _blob_angle(labels[y:y + h, x:x + w] == i) if area >= 5 else 0.0
            out.append(Detection(centroid=(float(cents[i][0]) + bx + 0.5,
                                           float(cents[i][1]) + by + 0.5),
                                 bbox=(x + bx, y + by, w, h), area=area, confidence=float(conf),
                                 angle=angle))
        out.sort(key=lambda d: d.area, reverse=True)
        return out

    def detect(self, rgb: np.ndarray) -> Detection | None:
        """The largest blob, or None when there is none."""
        dets = self.detect_all(rgb)
        return dets[0] if dets else None


def _blob_angle(blob: np.ndarray) -> float:
    """Rotation (deg, [0, 90)) of a binary blob's minimum-area rectangle."""
    contours, _ = cv2.findContours(blob.astype(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return 0.0
    (_, _), (_, _), a = cv2.minAreaRect(max(contours, key=cv2.contourArea))
    return float(a % 90.0)
