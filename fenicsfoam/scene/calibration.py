"""A calibration file (``calibration.json``, written by ``fenicsfoam calibrate``) as a scene reads it.

The scene key ``E_solid = {calibration = "calibration.json"}`` takes a foam region's modulus from such a file;
:mod:`fenicsfoam.calibrate` writes them and re-exports these names.

A calibrated ``E_solid`` absorbs the bias of the foam table it was calibrated through (the same measurement gives
another modulus through another table), so the file records the tables its scene's foam regions read
(``foam_tables``: each table's label, the shipped name or the CSV path, and the SHA-256 of its file) and a region
takes the modulus only if its own table is one of them (:func:`check_calibration_table`). Tables are compared by
their contents: a CSV copy of a recorded table matches, a recorded table regenerated since does not. A file without
the record (written before it existed) is taken as calibrated through the default table, :data:`LEGACY_TABLE`
(``"cube"``, the only table the scenes read then; no longer the default).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from foambase.errors import InputError
from foambase.files import check_input_file

__all__ = ["LEGACY_TABLE", "CalibrationError", "calibration_tables", "check_calibration_table", "foam_table_records",
           "read_calibration"]

#: The foam table of a calibration file without a ``foam_tables`` record.
LEGACY_TABLE = "cube"


class CalibrationError(InputError):
    """A calibration cannot be done: bad input, or a target no ``E_solid`` reaches; the message says which value.

    An :class:`~foambase.errors.InputError` (a ``ValueError``): the command line exits with status 2.
    """


def _load(path: Path) -> dict[str, Any]:
    try:
        check_input_file(path, "calibration file", max_bytes=1 << 20)  # never opens a FIFO or reads /dev/zero
        data = json.loads(path.read_text(encoding="utf-8"))
    except InputError as exc:
        raise CalibrationError(f"cannot read {exc}") from exc
    except UnicodeDecodeError as exc:
        raise CalibrationError(f"calibration file {str(path)!r} is not UTF-8 text (byte {exc.start})") from exc
    except OSError as exc:
        raise CalibrationError(f"cannot read calibration file {str(path)!r}: {exc.strerror}") from exc
    except json.JSONDecodeError as exc:
        raise CalibrationError(f"calibration file {str(path)!r} is not valid JSON: {exc}") from exc
    if not isinstance(data, dict):
        raise CalibrationError(f"calibration file {str(path)!r}: expected a JSON object, got {type(data).__name__}")
    return data


def read_calibration(path: str | os.PathLike) -> float:
    """``E_solid`` (Pa) of a ``calibration.json``; :class:`CalibrationError` names the file and what is wrong."""
    path = Path(path)
    E = _load(path).get("E_solid")
    if isinstance(E, bool) or not isinstance(E, int | float) or not (math.isfinite(E) and E > 0):
        raise CalibrationError(f"calibration file {str(path)!r}: 'E_solid' must be a positive modulus in Pa, "
                               f"got {E!r}")
    return float(E)


def foam_table_records(tables: Iterable[tuple[str, str | os.PathLike | None]]) -> list[dict[str, Any]]:
    """The ``foam_tables`` record of a calibration: one entry per distinct table, from ``(region, table)`` pairs.

    ``table`` as a foam region holds it (``None``: the default table; a shipped name; a CSV path). Each entry
    is ``{"table": label, "sha256": digest of its file, "regions": [names]}``
    (:func:`homogenization.tables.resolve_table`, :func:`~homogenization.tables.table_sha256`).
    """
    from homogenization.tables import resolve_table, table_sha256

    records: dict[str, dict[str, Any]] = {}
    for region, table in tables:
        label, _ = resolve_table(table)
        digest = table_sha256(table)
        records.setdefault(digest, {"table": label, "sha256": digest, "regions": []})["regions"].append(region)
    return list(records.values())


def calibration_tables(path: str | os.PathLike) -> list[dict[str, Any]]:
    """The ``foam_tables`` record of a ``calibration.json`` (entries ``{"table", "sha256", ...}``).

    A file without it gives ``[{"table": "cube", "sha256": <the shipped cube table's digest now>, "legacy":
    True}]`` (:data:`LEGACY_TABLE`). :class:`CalibrationError` names a malformed record.
    """
    path = Path(path)
    data = _load(path)
    if "foam_tables" not in data:
        from homogenization.tables import table_sha256
        return [{"table": LEGACY_TABLE, "sha256": table_sha256(LEGACY_TABLE), "legacy": True}]
    records = data["foam_tables"]
    if not (isinstance(records, list) and records and all(
            isinstance(r, dict) and isinstance(r.get("table"), str) and isinstance(r.get("sha256"), str)
            for r in records)):
        raise CalibrationError(f"calibration file {str(path)!r}: 'foam_tables' must be a non-empty list of "
                               f"{{\"table\": label, \"sha256\": digest}}, got {records!r}")
    return records


def check_calibration_table(path: str | os.PathLike, table: str | os.PathLike | None, region: str) -> None:
    """Refuse a calibration for a foam region whose table is not one the calibration was made through.

    ``table`` is the region's (``None``: the default table); tables are compared by the SHA-256 of their
    files. :class:`CalibrationError` names the region, both tables and what to do.
    """
    from homogenization.tables import resolve_table, table_sha256

    records = calibration_tables(path)
    label, _ = resolve_table(table)
    digest = table_sha256(table)
    if any(r["sha256"] == digest for r in records):
        return
    through = " and ".join(repr(r["table"]) for r in records)
    legacy = (f" (a calibration file without a 'foam_tables' record is taken as calibrated through the former "
              f"default table {LEGACY_TABLE!r})" if any(r.get("legacy") for r in records) else "")
    changed = [r for r in records if r["table"] == label]
    if changed:
        raise CalibrationError(
            f"region {region!r} reads foam table {label!r}, which has changed since calibration file {str(path)!r} "
            f"was calibrated through it (sha256 {changed[0]['sha256'][:12]}… then, {digest[:12]}… now): calibrate "
            "again (fenicsfoam calibrate) through the current table")
    raise CalibrationError(
        f"region {region!r} reads foam table {label!r}, but calibration file {str(path)!r} was calibrated through "
        f"foam table {through}{legacy}: a calibrated E_solid absorbs the bias of its table and holds only for "
        f"regions that read it. Calibrate through {label!r} (give the calibration scene's foam regions "
        f"table = {label!r} and run fenicsfoam calibrate), or give region {region!r} the calibration's table")
