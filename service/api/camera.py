"""The camera of a stereo request: numbers in the query, a calibration file in the ``calib`` field, or none.

``/depth`` and ``/pointcloud`` need one (``focal_px`` and ``baseline_m``, optionally ``cx``, ``cy`` and
``doffs``, or a ``calib`` file: Middlebury, KITTI, OpenCV, read by :mod:`service.calibration`);
``/disparity`` takes a file too, so that a raw rig's pair is rectified before matching as on the other
routes. Either way the result is one :class:`~service.calibration.StereoCalibration` for the images' size,
which :func:`calibration_header` describes in the ``X-ADSM-Calibration`` answer header.
"""

from __future__ import annotations

import dataclasses

from service.api.refusals import BadRequest
from service.calibration import StereoCalibration
from service.calibration.upload import parse_calibration

CALIBRATION_FIELD = "calib"  # the optional multipart file


@dataclasses.dataclass(frozen=True)
class CalibrationFile:
    """The ``calib`` part as received: the client's file name and the bytes."""

    filename: str | None
    data: bytes


@dataclasses.dataclass(frozen=True, kw_only=True)
class CameraRequest:
    """What the query says about the camera; :meth:`resolve` adds the ``calib`` file once the body is read."""

    required: bool  # /depth, /pointcloud: without a camera there is no metric answer
    focal_px: float | None = None
    baseline_m: float | None = None
    cx: float | None = None
    cy: float | None = None
    doffs: float | None = None
    calib_units: str | None = None  # OpenCV files only: the unit of T (m, cm, mm)
    calib_rectified: bool | None = None  # the images are rectified already: ignore a raw rig's K D R

    def resolve(self, calib: CalibrationFile | None, height: int, width: int) -> StereoCalibration | None:
        """The camera for ``height`` x ``width`` images; BadRequest or CalibrationError (both 400) when it is
        given twice, by halves, not at all where it is needed, or in a file that cannot be used."""
        by_hand = {name: value for name in ("focal_px", "baseline_m", "cx", "cy", "doffs")
                   if (value := getattr(self, name)) is not None}
        if calib is not None:
            if by_hand:
                raise BadRequest(f"give either a calib file or {', '.join(by_hand)} in the query, not both "
                                 "(the file holds the whole camera)")
            calibration = parse_calibration(
                calib.data, filename=calib.filename, image_size=(height, width),
                units=self.calib_units or "m", rectified=bool(self.calib_rectified),
            )
            return calibration.for_size(height, width)
        file_only = [name for name in ("calib_units", "calib_rectified") if getattr(self, name) is not None]
        if file_only:
            raise BadRequest(f"{file_only[0]} describes a calibration file: send one in the multipart field "
                             f"'{CALIBRATION_FIELD}', or leave {file_only[0]} out")
        if self.focal_px is None or self.baseline_m is None:
            if self.focal_px is not None or self.baseline_m is not None:
                given, missing = (("focal_px", "baseline_m") if self.focal_px is not None
                                  else ("baseline_m", "focal_px"))
                raise BadRequest(f"{given} needs {missing} too (or a calib file instead of both)")
            if self.required:
                raise BadRequest("this route needs the camera: focal_px and baseline_m in the query, or a "
                                 f"calibration file in the multipart field '{CALIBRATION_FIELD}'")
            return None  # /disparity takes no camera numbers, so nothing else can be given here
        return StereoCalibration(
            focal_px=self.focal_px, baseline_m=self.baseline_m,
            cx=(width - 1) / 2 if self.cx is None else self.cx,
            cy=(height - 1) / 2 if self.cy is None else self.cy,
            doffs=0.0 if self.doffs is None else self.doffs,
        )


def calibration_header(calibration: StereoCalibration, *, rectified: bool) -> str:
    """``X-ADSM-Calibration``: the camera the answer was computed with, ``key=value`` pairs joined by ``; ``
    (``source`` quoted; absent for numbers given in the query)."""
    fields = [f"focal_px={calibration.focal_px:.10g}", f"focal_y_px={calibration.fy:.10g}",
              f"baseline_m={calibration.baseline_m:.10g}", f"cx={calibration.cx:.10g}",
              f"cy={calibration.cy:.10g}", f"doffs={calibration.doffs:.10g}",
              f"rectified={'true' if rectified else 'false'}"]
    if calibration.source:  # the client's file name, sanitised by parse_calibration: header-safe
        fields.append(f'source="{calibration.source}"')
    return "; ".join(fields)
