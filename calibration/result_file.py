"""The hand-eye result file: the JSON ``weldcell calibrate hand-eye`` writes and the cell's ``[hand_eye] path``
reads, both here, so the writer and the reader agree on its ``format`` (layout: docs/calibration.md, section 5).

Written atomically (:func:`write_result_file`), the previous file kept as ``FILE.prev``; read back by
:func:`read_X_tool_camera`, which refuses a file without ``"format": "weldcell-hand-eye/1"``.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from calibration.board import CharucoBoardSpec
from calibration.errors import CalibrationError
from calibration.handeye import HandEyeMode, HandEyeResult
from calibration.verdict import Assessment, Verification, solved_transforms
from calibration.views import ViewRecord
from perception.capture import CameraIntrinsics
from perception.transforms import TransformError, check_X

FloatArray = NDArray[np.float64]

RESULT_FORMAT = "weldcell-hand-eye/1"
"""The ``format`` key of every result file; a reader refuses any other value (a new layout gets a new number)."""
PREVIOUS_SUFFIX = ".prev"


class ResultFileError(CalibrationError):
    """A hand-eye result file that cannot be read, or is not a weldcell hand-eye result of a known format."""


def result_document(
    result: HandEyeResult,
    *,
    views: Sequence[ViewRecord],
    verification: Verification,
    assessment: Assessment,
    intrinsics: CameraIntrinsics,
    board: CharucoBoardSpec,
    date: datetime | None = None,
    source: str = "",
) -> dict[str, Any]:
    """The JSON object of a result file (see docs/calibration.md): the solved transforms (metres), the method,
    the date, the residuals (px, mm, deg), the verification, the verdict, the board, the intrinsics and every
    view (its robot pose, its measured board pose, or why it was skipped)."""
    X_hand_eye, X_board = solved_transforms(result)
    names = (
        ("X_tool_camera", "X_base_board")
        if result.mode is HandEyeMode.EYE_IN_HAND
        else ("X_base_camera", "X_tool_board")
    )
    used = [v for v in views if v.usable]
    assert result.view_residuals_px is not None and result.rms_px is not None
    per_view = [
        {"view": v.index + 1, "px": round(float(px), 4), "mm": round(float(mm), 4), "deg": round(float(deg), 5)}
        for v, px, mm, deg in zip(
            used, result.view_residuals_px, result.view_residuals_mm, result.view_residuals_deg, strict=True
        )
    ]
    view_list: list[dict[str, Any]] = []
    for v in views:
        entry: dict[str, Any] = {"view": v.index + 1, "X_base_tool": _matrix(v.X_base_tool)}
        if v.observation is not None:
            entry["X_camera_board"] = _matrix(v.observation.X_camera_board)
            entry["corners"] = v.observation.n_corners
            entry["fit_rms_px"] = round(v.observation.rms_px, 4)
        if v.skipped:
            entry["skipped"] = v.skipped
        view_list.append(entry)
    when = date or datetime.now(UTC)
    return {
        "format": RESULT_FORMAT,
        names[0]: _matrix(X_hand_eye),
        names[1]: _matrix(X_board),
        "mode": result.mode.value,
        "method": result.method,
        "start_method": result.start_method,
        "date": when.isoformat(timespec="seconds"),
        "n_views": result.n_views,
        "n_views_skipped": len(views) - len(used),
        "verdict": assessment.verdict.value,
        "verdict_reasons": list(assessment.reasons),
        "residuals": {
            "rms_px": round(result.rms_px, 4),
            "rms_mm": round(result.rms_mm, 4),
            "rms_deg": round(result.rms_deg, 5),
            "per_view": per_view,
        },
        "verification": {
            "X_base_tool": _matrix(verification.X_base_tool),
            "corners": verification.n_corners,
            "rms_px": round(verification.rms_px, 4),
            "max_px": round(verification.max_px, 4),
            "translation_mm": round(verification.translation_mm, 4),
            "rotation_deg": round(verification.rotation_deg, 5),
        },
        "board": {
            "squares_x": board.squares_x,
            "squares_y": board.squares_y,
            "square_length_m": board.square_length_m,
            "marker_length_m": board.marker_length_m,
            "dictionary": board.dictionary,
            "legacy_pattern": board.legacy_pattern,
        },
        "intrinsics": intrinsics.to_json(),
        "source": source,
        "views": view_list,
    }


def _matrix(X: ArrayLike) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(X, dtype=np.float64)]


def write_result_file(path: str | os.PathLike[str], document: dict[str, Any]) -> Path | None:
    """Write ``document`` (a result file's object, ``"format"`` :data:`RESULT_FORMAT`, see :func:`result_document`)
    as JSON to ``path`` atomically, keeping an existing file as ``path + ".prev"``.

    The new content goes to a temporary file in the same folder (flushed to disk) first; then the current file
    is copied to a temporary file and renamed onto ``.prev``; then the new file is renamed onto ``path``. Each
    rename is atomic, so ``path`` always holds a complete file, old or new, whatever interrupts this. Returns the
    ``.prev`` path when there was a previous file, else None.
    """
    if document.get("format") != RESULT_FORMAT:
        raise ResultFileError(
            f"refusing to write a hand-eye file whose format is {document.get('format')!r}, not {RESULT_FORMAT!r}"
        )
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    text = _json_text(document)
    new_tmp = _temp_beside(out)
    previous: Path | None = None
    try:
        with open(new_tmp, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        if out.exists():
            previous = out.with_name(out.name + PREVIOUS_SUFFIX)
            prev_tmp = _temp_beside(previous)
            try:
                shutil.copy2(out, prev_tmp)
                os.replace(prev_tmp, previous)
            except BaseException:
                prev_tmp.unlink(missing_ok=True)
                raise
        os.replace(new_tmp, out)
    except BaseException:
        new_tmp.unlink(missing_ok=True)
        raise
    return previous


def _json_text(document: dict[str, Any]) -> str:
    """Indented JSON with every innermost list of numbers on one line (a 4x4 matrix reads as 4 rows)."""
    text = json.dumps(document, indent=1, allow_nan=False)
    text = _INNER_LIST.sub(lambda m: "[" + ", ".join(v.strip() for v in m.group(1).split(",")) + "]", text)
    return text + "\n"


# An innermost list as json.dumps(indent=...) lays it out: "[", newline, numbers, newline, "]". A JSON string
# never holds a raw newline, so text inside strings is never touched.
_INNER_LIST = re.compile(r"\[\n\s*([-+0-9.eE,\s]+?)\n\s*\]")


def _temp_beside(path: Path) -> Path:
    fd, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    os.chmod(name, 0o666 & ~_umask())  # mkstemp makes 0600; the result is read by other users of the cell
    return Path(name)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def read_result_file(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The JSON object of the result file at ``path`` after checking its ``format``; :class:`ResultFileError`
    saying what is wrong (unreadable, not JSON, not an object, no or another ``format``) otherwise."""
    file = Path(path)
    try:
        obj = json.loads(file.read_text(encoding="utf-8"))
    except OSError as err:
        raise ResultFileError(f"cannot read the hand-eye file {file}: {err.strerror or err}") from err
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise ResultFileError(f"the hand-eye file {file} is not valid JSON: {err}") from err
    if not isinstance(obj, dict):
        raise ResultFileError(f"the hand-eye file {file} holds a JSON {type(obj).__name__}, not an object")
    found = obj.get("format")
    if found != RESULT_FORMAT:
        what = "has no 'format' key" if "format" not in obj else f"has format {found!r}"
        raise ResultFileError(
            f"the hand-eye file {file} {what}; this weldcell reads {RESULT_FORMAT!r} files, as "
            '`weldcell calibrate hand-eye` writes them (add "format": "weldcell-hand-eye/1" to a file written '
            "by hand)"
        )
    return obj


def read_X_tool_camera(path: str | os.PathLike[str]) -> FloatArray:
    """(4, 4) ``X_tool_camera`` (metres) of an eye-in-hand result file (:func:`read_result_file`)."""
    obj = read_result_file(path)
    if "X_tool_camera" not in obj:
        raise ResultFileError(
            f"the hand-eye file {path} has no 'X_tool_camera' key"
            + (" (it is an eye-to-hand result)" if "X_base_camera" in obj else "")
        )
    try:
        return check_X(np.asarray(obj["X_tool_camera"], dtype=np.float64), name="X_tool_camera")
    except (TransformError, TypeError, ValueError) as err:
        raise ResultFileError(f"{path}: {err}") from err
