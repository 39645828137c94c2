"""The common estimator interface of the harness, and adapters for the project's own estimators.

An estimator is any object with

- ``name`` (str), ``kind`` ("analytical", "filter", "peer", "learned"), ``causal`` (bool: each
  output uses only past and current samples), ``uses_mag`` (bool: 9-D; 6-D estimates get one
  constant heading alignment per run before heading metrics, 9-D ones none), and
- ``estimate(record) -> pandas.DataFrame`` with one row per record row: ``t_s``,
  ``q_est_w..z`` (body FRD → NED), optionally ``sigma_rad`` (per-axis σ of the 2-D tilt error)
  and ``gyr_bias_est_{x,y,z}_rad_s``. NaN rows mean "no estimate yet" (e.g. a window not yet full).

The harness times ``estimate`` itself (µs per sample), so TE-PINN, an LSTM or any later model plugs
in by providing this interface. Filters restart at every record segment (a gap or a reboot).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd

from ..record import EST_BIAS_COLS, EST_Q_COLS, FlightRecord, segment_slices
from .names import reads_as_mode


def estimate_frame(t_s, q, sigma=None, bias=None) -> pd.DataFrame:
    df = pd.DataFrame({"t_s": np.asarray(t_s, np.float64)})
    q = np.asarray(q, np.float64)
    for i, c in enumerate(EST_Q_COLS):
        df[c] = q[:, i]
    if sigma is not None:
        df["sigma_rad"] = np.asarray(sigma, np.float64)
    if bias is not None:
        bias = np.asarray(bias, np.float64)
        for i, c in enumerate(EST_BIAS_COLS):
            df[c] = bias[:, i]
    return df


def record_mag(record: FlightRecord) -> np.ndarray | None:
    """The magnetometer (µT) or None when the record has none."""
    mag = record.mag_ut
    return mag if np.any(np.all(np.isfinite(mag), axis=1)) else None


class FilterEstimator:
    """Runs a baseline filter (batch API of :mod:`.filters`) per record segment."""

    def __init__(self, flt, name: str | None = None, use_mag: bool = False, kind: str = "filter", q0_fn=None):
        self.filter = flt
        self.uses_mag = bool(use_mag)
        self.name = name or (flt.name + ("-9d" if use_mag else ""))
        self.kind = kind
        self.causal = True
        self.q0_fn = q0_fn  # optional (record, slice) -> initial quaternion

    def estimate(self, record: FlightRecord) -> pd.DataFrame:
        n = len(record)
        q = np.full((n, 4), np.nan)
        sigma = bias = None
        gyr, acc, t = record.gyr_rad_s, record.acc_m_s2, record.t_s
        mag = record_mag(record) if self.uses_mag else None
        for sl in segment_slices(record.segment):
            kw = {}
            if self.q0_fn is not None:
                kw["q0"] = self.q0_fn(record, sl)
            out = self.filter.estimate(gyr[sl], acc[sl], t[sl], None if mag is None else mag[sl], **kw)
            q[sl] = out["q_nb_wxyz"]
            if "sigma_rad" in out:
                sigma = np.full(n, np.nan) if sigma is None else sigma
                sigma[sl] = out["sigma_rad"]
            if "bias_rad_s" in out:
                bias = np.full((n, 3), np.nan) if bias is None else bias
                bias[sl] = out["bias_rad_s"]
        return estimate_frame(t, q, sigma, bias)


class TepinnEstimator:
    """TE-PINN from a checkpoint: ``tepinn_flight.model.estimate.estimate_record``."""

    kind = "learned"

    exported_in_memory = False  # a checkpoint run in onnxruntime without an export of it beside it

    def __init__(self, model, fusion, name: str = "tepinn", checkpoint: str | None = None):
        self.model, self.fusion, self.name, self.checkpoint = model, fusion, name, checkpoint

    @property
    def runtime(self) -> str:
        """Where the network runs: ``onnx`` (onnxruntime) or ``torch``."""
        from ..model.runtime import OnnxRunner

        return "onnx" if isinstance(self.model, OnnxRunner) else "torch"

    @property
    def causal(self) -> bool:
        """Each estimate from past samples only: not where an offline step reads the whole record
        (the anchored estimator's gyro self-calibration, GNSS aid or smoothing: ``OFFLINE_STEPS``)."""
        from ..model.estimate import OFFLINE_STEPS

        return not any(getattr(self.fusion, step, False) for step in OFFLINE_STEPS)

    @property
    def uses_mag(self) -> bool:
        """9-D: the anchored estimator in mode 9d/auto (absolute heading from the magnetometer)."""
        return getattr(self.fusion, "mode", "6d") != "6d"

    def nine_d(self) -> TepinnEstimator | None:
        """The same model in 9-D (``name-9d``: the magnetometer's heading where a record has one,
        else 6-D), or None for a checkpoint that runs the older network-centred fusion."""
        import dataclasses

        from ..model.anchor import AnchorConfig

        if not isinstance(self.fusion, AnchorConfig):
            return None
        return TepinnEstimator(self.model, dataclasses.replace(self.fusion, mode="auto"), self.name + "-9d", self.checkpoint)

    def strided(self, n: int) -> TepinnEstimator | None:
        """The same model running every ``n``-th window of a busy block (``name-strideN``:
        :func:`~tepinn_flight.model.anchor.with_busy_stride`), or None for a checkpoint that runs the
        older network-centred fusion."""
        from ..model.anchor import AnchorConfig, with_busy_stride

        if not isinstance(self.fusion, AnchorConfig):
            return None
        return TepinnEstimator(self.model, with_busy_stride(self.fusion, n), f"{self.name}-stride{n}", self.checkpoint)

    def smoothed(self) -> TepinnEstimator | None:
        """The same model with the offline tilt smoothing on (``name-smooth``: for a checkpoint that does
        not smooth, one written before session 25;
        :mod:`~tepinn_flight.model.smoother`), or None for a checkpoint that runs the older
        network-centred fusion."""
        import dataclasses

        from ..model.anchor import AnchorConfig

        if not isinstance(self.fusion, AnchorConfig):
            return None
        return TepinnEstimator(self.model, dataclasses.replace(self.fusion, smoother=True), self.name + "-smooth", self.checkpoint)

    def unsmoothed(self) -> TepinnEstimator | None:
        """The same model without the offline tilt smoothing (``name-nosmooth``: ``estimate --no-smooth``; the
        record's GNSS aid and self-calibrations still apply: :meth:`live` turns them off too), or None where it
        does not smooth (the older fusion, a checkpoint written before session 25)."""
        import dataclasses

        if not getattr(self.fusion, "smoother", False):
            return None
        return TepinnEstimator(self.model, dataclasses.replace(self.fusion, smoother=False), self.name + "-nosmooth", self.checkpoint)

    def live(self) -> TepinnEstimator | None:
        """The same model as the bridge runs it (``name-live``): every sample of a record pushed through the live
        estimator in order (:func:`~tepinn_flight.model.streaming.stream_record`), so none of the steps that read the
        whole record applies (the smoothing, the GNSS aid, the gyro's self-calibration) and the accelerometer's scale
        is read as the bridge reads it, from the first quiet seconds on. 6-D. None for a model with no offline step
        (the older network-centred fusion: its offline estimate is the live one) and for a 9-D one."""
        from ..model.estimate import OFFLINE_STEPS

        if self.uses_mag or not any(getattr(self.fusion, step, False) for step in OFFLINE_STEPS):
            return None
        return LiveTepinnEstimator(self.model, self.fusion, self.name + "-live", self.checkpoint)

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike, name: str | None = None, runtime: str | None = None,
                        threads: int | None = None) -> TepinnEstimator:  # fmt: skip
        """A checkpoint (``.pt``) or an export (``.onnx``) run in ``runtime``: ``torch`` (the module itself, as the
        benchmarks have always scored a checkpoint: the default for one), ``onnx`` (the default for an export) or ``auto`` (:func:`~tepinn_flight.model.runtime.load_runner`:
        what ``estimate`` runs — onnxruntime for an export, for a checkpoint with its export in sync beside it such as
        the shipped ones, or where torch is absent; equal to PyTorch to 1e-5)."""
        from ..model.runtime import is_onnx_path, load_runner, resolve_runtime

        if runtime is None:
            runtime = "onnx" if is_onnx_path(path) else "torch"
        ran, in_memory = os.fspath(path), False
        if resolve_runtime(path, runtime) == "torch":
            from ..model.checkpoint import load_model

            model, fusion, ckpt = load_model(path)
        else:
            from ..model.runtime import export_in_sync

            synced = None if is_onnx_path(path) else export_in_sync(path)
            model, fusion, ckpt = load_runner(path, runtime, threads)  # (an OnnxRunner: estimate_record takes it)
            if synced is not None:  # what ran is the export beside it (review61: the report had named the .pt)
                ran = os.fspath(synced)
            in_memory = not is_onnx_path(path) and synced is None
        if name is None:
            name = model.config.variant
            if (ckpt.get("loss_config") or {}).get("adaptive") is False:
                name += "-noadaptive"
        est = cls(model, fusion, name, ran)
        est.exported_in_memory = in_memory
        return est

    def estimate(self, record: FlightRecord) -> pd.DataFrame:
        from ..model.estimate import estimate_record

        return estimate_record(self.model, record, self.fusion)


class LiveTepinnEstimator(TepinnEstimator):
    """TE-PINN as the live bridge gives it (:meth:`TepinnEstimator.live`): causal, every estimate from past samples."""

    causal = True

    def live(self) -> None:
        return None

    def estimate(self, record: FlightRecord) -> pd.DataFrame:
        from ..model.streaming import stream_record

        q, sigma, bias = stream_record(self.model, record, self.fusion)
        return estimate_frame(record.t_s, q, sigma, bias)


def _shipped(path: Path, runtime: str) -> Path:
    """A shipped checkpoint, or its export beside it where ``runtime`` runs it in onnxruntime (as ``estimate`` takes
    the shipped model): the export is what a torch-less install can read."""
    from ..model.runtime import resolve_runtime

    onnx = path.with_suffix(".onnx")
    return onnx if onnx.is_file() and resolve_runtime(path, runtime) == "onnx" else path


def default_tepinn(note_sink: list | None = None, runtime: str = "auto"):
    """The shipped TE-PINN model in ``runtime`` (:meth:`TepinnEstimator.from_checkpoint`), or None (with a note)
    where there is none or it cannot run here."""
    from ..model.checkpoint import default_model_path

    path = Path(default_model_path())
    if not path.exists():
        if note_sink is not None:
            note_sink.append(f"TE-PINN skipped: no model given and no shipped default model at {path}")
        return None
    from ..errors import TepinnError

    try:
        return TepinnEstimator.from_checkpoint(_shipped(path, runtime), "tepinn", runtime)
    except TepinnError as exc:  # (--runtime torch without torch: said in one line as a note, the filters still scored)
        if note_sink is not None:
            note_sink.append(f"TE-PINN skipped: the shipped default model cannot be used ({exc})")
        return None


def default_learned(note_sink: list | None = None, runtime: str = "auto") -> list:
    """The shipped TE-PINN and, when shipped too, the LSTM baseline trained by the same code, in ``runtime``."""
    out = []
    est = default_tepinn(note_sink, runtime)
    if est is not None:
        out.append(est)
    try:
        from ..model.checkpoint import default_lstm_path

        path = Path(default_lstm_path())
        if path.exists():
            out.append(TepinnEstimator.from_checkpoint(_shipped(path, runtime), runtime=runtime))
        elif note_sink is not None:
            note_sink.append(f"LSTM baseline skipped: no shipped LSTM at {path}")
    except Exception as exc:  # a broken extra model must not stop the evaluation
        if note_sink is not None:
            note_sink.append(f"LSTM baseline skipped ({type(exc).__name__}: {exc})")
    return out


def learned_estimators(model_paths: list, note_sink: list | None = None, runtime: str = "auto") -> list:
    """TE-PINN/LSTM estimators from checkpoints or exports, named by variant (``tepinn``, ``lstm``, ...) and
    made unique with the run folder; without paths, the shipped models. ``runtime``: as ``estimate --runtime``."""
    if not model_paths:
        return default_learned(note_sink, runtime)
    out: list = []
    for m in model_paths:
        est = TepinnEstimator.from_checkpoint(m, runtime=runtime)
        if est.exported_in_memory and note_sink is not None:
            note_sink.append(f"{m}: no export made from it lies beside it; exported in memory for onnxruntime "
                             f"(`tepinn-flight export {m} -o {Path(m).with_suffix('.onnx')}` keeps one)")  # fmt: skip
        taken = {e.name for e in out}
        base, p = est.name, Path(m)
        # unique by the run folder, then the file's name, then a number (review61: a third model of one run folder
        # had taken the second's name, and the run was refused after loading every model); never a name that reads as
        # another model's variant (a run folder named "live": `tepinn-live` is the shipped model's --live column)
        for name in (base, f"{base}-{p.parent.name or p.stem}", f"{base}-{p.parent.name}-{p.stem}" if p.parent.name else None,
                     *(f"{base}-{k}" for k in range(2, len(model_paths) + 2))):  # fmt: skip
            if name and name not in taken and (name == base or not reads_as_mode(name)):
                est.name = name
                break
        out.append(est)
    return out
