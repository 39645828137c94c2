"""Network runners: the TE-PINN network behind one small interface, with or without PyTorch.

A runner takes a batch of token windows as numpy arrays and returns the window outputs the
estimators use, as float64 numpy arrays::

    runner.run(gyr, acc, count, t_rel, dt, mag, clip) -> {"q": (B, 4), "sigma": (B,),
                                                          "bias": (B, 3), "vel": (B, 3), "acc_v": (B, 3)}

with ``gyr``/``acc``/``mag`` (B, K, 3), ``count``/``t_rel``/``dt``/``clip`` (B, K) as in
:meth:`~tepinn_flight.model.network.TEPINN.forward` (K = ``runner.config.window_tokens``). A model
without the σ head gives σ = 2° and one without the velocity head zeros, as the estimators always
assumed. Two implementations:

* :class:`TorchRunner` wraps a :class:`~tepinn_flight.model.network.TEPINN` (imports torch);
* :class:`OnnxRunner` runs an ``.onnx`` file written by ``tepinn-flight export`` with onnxruntime
  (no torch); its metadata carries the checkpoint's model/anchor/fusion configs.

:func:`load_runner` opens a checkpoint or an ``.onnx`` file for a runtime ``torch``, ``onnx`` or
``auto`` (the file's own runtime; for a checkpoint without torch installed, the ``.onnx`` beside
it when there is one). This module imports neither torch nor onnxruntime at import time.
"""

from __future__ import annotations

import functools
import importlib.util
import json
import math
import os
import threading
from pathlib import Path

import numpy as np

from ..errors import ConfigError, TepinnError
from .checkpoint import estimator_settings, model_config_from
from .config import ModelConfig

INPUTS = ("gyr", "acc", "count", "t_rel", "dt", "mag", "clip")
OUTPUTS = ("q", "sigma", "bias", "vel", "acc_v")
RUNTIMES = ("auto", "torch", "onnx")
#: σ of a model without the σ head (rad)
DEFAULT_SIGMA_RAD = math.radians(2.0)
ONNX_FORMAT = "tepinn-flight-onnx"
ONNX_VERSION = 3
#: export versions this runner reads: 1 (the graph takes the windows), 2 (it takes their features),
#: 3 (it takes their features and ends at the heads' linear layers: GRAPH_OUTPUTS)
ONNX_VERSIONS_READ = (1, 2, 3)
#: onnxruntime runs a large batch this many windows at a time: a window's intermediate arrays (its 80 × 80
#: attention per head among them) then stay in the core's cache. A window cost 17–22 % less in chunks of 4–32 than
#: in one run of 128 (session 41, `runs/exp41/chunk_sweep.py`: one thread 529 → 433–456 µs, two threads side by
#: side 292 → 226–237 µs a window). A window's outputs are those of one run to float32 round-off (in that check
#: the same bits in chunks of 16 and 64; σ's one-column product 1e-8 off in batches of 1 and 7;
#: tests/test_onnx_runtime.py)
CHUNK_WINDOWS = 16
#: a version-3 graph's outputs; the runner computes ``q`` from them (:mod:`.head_physics`)
GRAPH_OUTPUTS = ("q_head", "pool", "sigma", "bias", "vel", "acc_v")


def torch_available() -> bool:
    return importlib.util.find_spec("torch") is not None


def is_onnx_path(path) -> bool:
    return Path(path).suffix.lower() == ".onnx"


def _complete(out: dict, present, b: int) -> dict:
    """float64 outputs with the estimators' defaults for heads the model does not have."""
    res = {}
    for k in OUTPUTS:
        if k in present and k in out:
            res[k] = np.asarray(out[k], dtype=np.float64)
        elif k == "sigma":
            res[k] = np.full(b, DEFAULT_SIGMA_RAD)
        else:
            res[k] = np.zeros((b, 3))
    return res


class NetworkRunner:
    """Interface: ``config`` (:class:`ModelConfig`), ``name``, :meth:`run`, :meth:`set_threads`."""

    name = "?"
    config: ModelConfig

    def run(self, gyr, acc, count, t_rel, dt, mag, clip) -> dict:  # pragma: no cover - interface
        raise NotImplementedError

    def set_threads(self, n: int | None) -> None:
        """CPU threads of the runtime (None/0: leave the runtime's choice)."""


class TorchRunner(NetworkRunner):
    """A TE-PINN module in PyTorch (its dtype and mode as given; CPU)."""

    name = "torch"

    def __init__(self, model):
        self.model = model
        self.config = model.config
        self.dtype = next(model.parameters()).dtype

    def set_threads(self, n: int | None) -> None:
        if n:
            import torch

            torch.set_num_threads(n)

    def run(self, gyr, acc, count, t_rel, dt, mag, clip) -> dict:
        import torch

        with torch.inference_mode():
            args = [torch.as_tensor(x, dtype=self.dtype) for x in (gyr, acc, count, t_rel, dt, mag, clip)]
            out = self.model(*args)
            out = {k: out[k].double().numpy() for k in OUTPUTS if k in out}
        return _complete(out, out.keys(), len(gyr))


def read_onnx_metadata(path) -> dict:
    """The JSON metadata of an exported model (``metadata_props``), values decoded."""
    import onnxruntime as ort

    try:
        sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 - onnxruntime raises its own types
        raise ConfigError(f"{path}: not a readable ONNX model ({_first_line(exc)})") from None
    return _decode_meta(sess.get_modelmeta().custom_metadata_map, path)


def _decode_meta(raw: dict, path) -> dict:
    if raw.get("format") != ONNX_FORMAT:
        raise ConfigError(f"{path}: not a tepinn-flight ONNX export (no '{ONNX_FORMAT}' metadata)")
    meta = {}
    for k, v in raw.items():
        try:
            meta[k] = json.loads(v)
        except ValueError:
            meta[k] = v
    if meta.get("version") not in ONNX_VERSIONS_READ:
        raise ConfigError(f"{path}: unknown export version {meta.get('version')!r} (this tepinn-flight reads "
                          f"{', '.join(map(str, ONNX_VERSIONS_READ))})")  # fmt: skip
    return meta


def _first_line(exc: BaseException) -> str:
    return ((str(exc).strip().splitlines() or [type(exc).__name__])[0])[:200]


class OnnxRunner(NetworkRunner):
    """An ``.onnx`` export (``tepinn-flight export``) in onnxruntime on the CPU. ``model`` is a
    path or the serialized model bytes."""

    name = "onnx"

    def __init__(self, model, threads: int | None = None):
        import onnxruntime as ort

        self._ort = ort
        self._src = model if isinstance(model, (bytes, bytearray)) else str(model)
        self._label = "<bytes>" if isinstance(model, (bytes, bytearray)) else str(model)
        self.threads = None
        self._open(threads)
        self.meta = _decode_meta(self.session.get_modelmeta().custom_metadata_map, self._label)
        try:
            self.config = model_config_from(self.meta)
        except ConfigError as exc:  # (review60: unnamed, or "internal error: KeyError")
            raise ConfigError(f"{self._label}: its model_config: {exc.reason}") from None
        except (KeyError, TypeError, ValueError, AttributeError):
            raise ConfigError(f"{self._label}: export without a sound 'model_config' (a damaged or hand-edited "
                              "file)") from None  # fmt: skip
        self.present = set(self.meta.get("outputs_present", OUTPUTS))
        self.input_names = [i.name for i in self.session.get_inputs()]
        self.output_names = [o.name for o in self.session.get_outputs()]
        self._check_graph()
        self.sensor = None  # version 2 on: the features are computed here, with the trained sensor model
        self.physics_head = self.meta["version"] >= 3  # version 3: and the attitude from the heads' outputs
        if self.meta["version"] >= 2:
            from .window_features import SensorValues

            try:
                self.sensor = SensorValues.from_json(self.meta["sensor_model"])
            except (KeyError, TypeError, ValueError, IndexError) as exc:
                why = str(exc) if isinstance(exc, ValueError) else "missing or malformed"
                raise ConfigError(f"{self._label}: export version 2 without a sound 'sensor_model' ({why})") from None

    def _check_graph(self) -> None:
        """Refuse an export whose graph does not take what its metadata describes — inputs the runtime does not make
        for its version, windows of another length (review60: a hand-edited file failed at its first window, in the
        bridge mid-flight)."""
        from .window_features import feature_names

        made = set(feature_names(self.config)) if self.meta["version"] >= 2 else set(INPUTS)
        unknown = [n for n in self.input_names if n not in made]
        if unknown:
            raise ConfigError(f"{self._label}: its graph takes {', '.join(unknown)}, which an export of version "
                              f"{self.meta['version']} is not given: a damaged or hand-edited file")  # fmt: skip
        k = self.config.window_tokens
        for i in self.session.get_inputs():
            dims = list(i.shape)
            if len(dims) >= 2 and isinstance(dims[1], int) and dims[1] != k:
                raise ConfigError(f"{self._label}: its graph takes windows of {dims[1]} tokens ({i.name}), its "
                                  f"model_config {k}: a damaged or hand-edited file")  # fmt: skip

    def _open(self, threads: int | None) -> None:
        # one thread per run; with n threads a batch is cut into n parts run side by side (the
        # network's many small operators do not spread over threads inside one run: on 2 cores a
        # batch of 25 windows took 8.4–10.3 ms with 2 intra-op threads, 5.5–7.0 ms as two halves)
        n = int(threads) if threads else (os.cpu_count() or 1)
        so = self._ort.SessionOptions()
        so.intra_op_num_threads = 1
        so.inter_op_num_threads = 1
        try:
            self.session = self._ort.InferenceSession(self._src, so, providers=["CPUExecutionProvider"])
        except Exception as exc:  # noqa: BLE001
            raise ConfigError(f"{self._label}: not a readable ONNX model ({_first_line(exc)})") from None
        self.threads = threads
        self.workers = max(1, n)
        self._io = threading.local()  # run()'s I/O binding on this session, per thread, made on first use
        if getattr(self, "_pool", None) is not None:  # re-opened with another thread count
            self._pool.shutdown(wait=False)
        self._pool = None

    def set_threads(self, n: int | None) -> None:
        if n and n != self.threads:
            self._open(n)

    def run(self, gyr, acc, count, t_rel, dt, mag, clip) -> dict:
        if self.sensor is not None:
            from .window_features import window_features

            arrays = window_features(self.config, self.sensor, gyr, acc, count, t_rel, dt, mag, clip)
            # (a version-3 graph takes x and t_rel only: the physics features are read by its tail, below)
        else:
            arrays = dict(zip(INPUTS, (gyr, acc, count, t_rel, dt, mag, clip)))
        b = len(gyr)
        parts = min(self.workers, b)
        if parts < 2 and b > CHUNK_WINDOWS:  # one thread, a large batch: in chunks
            feed = {k: np.ascontiguousarray(arrays[k], dtype=np.float32) for k in self.input_names}
            res = self._run_chunks(feed)
        elif parts < 2:  # one run: through an I/O binding (the live path's batch of one: ~10 % of a window's run was
            # run()'s own conversion of the feed and the outputs; the same kernels, the same bits). The binding is
            # made once per thread and input shapes, on buffers of its own: later runs of those shapes copy the
            # inputs into them and read the outputs from buffers bound once (binding anew cost ~15 µs a window)
            shapes = tuple(np.shape(arrays[k]) for k in self.input_names)
            bound = getattr(self._io, "bound", None)  # one per thread: a binding is not to be shared between runs
            if bound is not None and bound[0] == shapes:
                _, io, ins, outs, _ = bound
                for k in self.input_names:
                    np.copyto(ins[k], arrays[k], casting="same_kind")  # float32, as the feed below
                self.session.run_with_iobinding(io)
                res = [o.copy() for o in outs]  # (the buffers are the next run's)
            else:
                io = self.session.io_binding()
                ins = {k: np.ascontiguousarray(arrays[k], dtype=np.float32).copy() for k in self.input_names}
                for k, v in ins.items():
                    io.bind_cpu_input(k, v)
                for k in self.output_names:
                    io.bind_output(k, "cpu")
                self.session.run_with_iobinding(io)
                res = io.copy_outputs_to_cpu()
                outs = [np.empty_like(r) for r in res]  # the outputs' buffers from now on
                values = [self._ort.OrtValue.ortvalue_from_numpy(o) for o in outs]
                for k, v in zip(self.output_names, values):
                    io.bind_ortvalue_output(k, v)
                self._io.bound = (shapes, io, ins, outs, values)
        else:
            # the batch in `parts` slices, side by side (onnxruntime lets go of the GIL); each window's outputs
            # depend on its own inputs only, equal to one run's within float32 round-off
            feed = {k: np.ascontiguousarray(arrays[k], dtype=np.float32) for k in self.input_names}
            if self._pool is None:
                from concurrent.futures import ThreadPoolExecutor

                self._pool = ThreadPoolExecutor(self.workers - 1, thread_name_prefix="onnx")
            cuts = np.linspace(0, b, parts + 1).round().astype(int)
            feeds = [{k: v[i:j] for k, v in feed.items()} for i, j in zip(cuts[:-1], cuts[1:])]
            futures = [self._pool.submit(self._run_chunks, f) for f in feeds[1:]]
            outs = [self._run_chunks(feeds[0])]  # the first slice in this thread
            outs += [f.result() for f in futures]
            res = [np.concatenate([o[i] for o in outs]) for i in range(len(self.output_names))]
        out = dict(zip(self.output_names, res))
        if self.physics_head:
            from .head_physics import window_attitude

            out["q"] = window_attitude(self.config, out, arrays)
        return _complete(out, self.present, b)

    def _run_chunks(self, feed: dict) -> list:
        """The session's outputs for the batch ``feed``, run :data:`CHUNK_WINDOWS` windows at a time."""
        b = len(next(iter(feed.values())))
        if b <= CHUNK_WINDOWS:
            return self.session.run(self.output_names, feed)
        outs = [self.session.run(self.output_names, {k: v[i : i + CHUNK_WINDOWS] for k, v in feed.items()})
                for i in range(0, b, CHUNK_WINDOWS)]  # fmt: skip
        return [np.concatenate([o[j] for o in outs]) for j in range(len(self.output_names))]


#: the modules only the [torch] extra installs: a verb that imports one where it is absent needs PyTorch
TORCH_MODULES = ("torch", "onnx")


def resolve_runtime(path, runtime: str = "auto") -> str:
    """``torch`` or ``onnx`` for ``path`` under ``runtime`` (see :func:`load_runner`)."""
    if runtime not in RUNTIMES:
        raise ConfigError(f"runtime must be one of {', '.join(RUNTIMES)}, not {runtime!r}")
    onnx_file = is_onnx_path(path)
    if runtime == "auto":
        return "onnx" if onnx_file or not torch_available() or export_in_sync(path) is not None else "torch"
    if runtime == "torch" and onnx_file:
        raise ConfigError(f"{path}: an .onnx model runs with the onnx runtime (--runtime onnx or auto)")
    if runtime == "torch" and not torch_available():
        raise ConfigError("--runtime torch needs PyTorch (pip install 'tepinn-flight[torch]')")
    return runtime


def check_model(path, runtime: str = "auto") -> None:
    """Refuse, in one line and before any work, a model file :func:`load_runner` would refuse: an ``.onnx`` that is no
    tepinn-flight export, a checkpoint that is none (the bridge had routed for 8 s before its worker met it), an
    export whose graph does not take what its metadata says, a checkpoint without torch and an export in sync
    (review60). Opens an export in onnxruntime as the worker does, or reads a checkpoint's archive listing: not torch,
    whose ~300 MB the bridge's main process on a companion computer does not otherwise load (its worker does, where
    it runs the checkpoint)."""
    path = Path(path)
    rt = resolve_runtime(path, runtime)
    if is_onnx_path(path) or (rt == "onnx" and (synced := export_in_sync(path)) is not None):
        # opened as the worker opens it: its graph checked against its metadata, its settings read
        runner = OnnxRunner(path if is_onnx_path(path) else synced, threads=1)
        try:
            estimator_settings(runner.meta)
        except TepinnError as exc:
            raise ConfigError(exc.reason, path) from None
    elif rt == "onnx" and not torch_available():  # what load_runner refuses here (review60: found 7 s into routing)
        raise _checkpoint_without_torch(path)
    elif not _is_torch_archive(path):
        raise ConfigError(f"{path}: not a readable checkpoint (not a torch checkpoint file)")


def _is_torch_archive(path: Path) -> bool:
    """Whether ``path`` is torch.save's archive (it holds <name>/data.pkl; a text file, an image, a truncated download,
    an export renamed do not), read from its zip listing alone."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as z:
            return any(n.endswith("/data.pkl") for n in z.namelist())
    except (OSError, zipfile.BadZipFile):
        return False


def _checkpoint_without_torch(path: Path) -> ConfigError:
    """Why the checkpoint ``path``, with no export in sync beside it, cannot run where torch is absent."""
    beside = path.with_suffix(".onnx")
    if path.is_dir():
        return ConfigError(f"{path}: a folder, not a model file")
    if not path.is_file():
        return ConfigError(f"{path}: no such model")
    if beside.is_file():  # without torch, an export beside it made from another file is not this model
        return ConfigError(f"{path}: {beside.name} beside it was not exported from this checkpoint (it changed since, "
                           "or it is another's), and without PyTorch the checkpoint cannot be read: export it again "
                           f"where torch is installed (tepinn-flight export {path.name} -o {beside.name}) or pass "
                           "the .onnx itself")  # fmt: skip
    if not _is_torch_archive(path):  # (review60: an export renamed .pt was told it needs PyTorch)
        return ConfigError(f"{path}: not a torch checkpoint file (an ONNX export is read under its .onnx name)")
    return ConfigError(f"{path}: a checkpoint needs PyTorch to be read; without it, export it once where torch is "
                       f"installed (tepinn-flight export {path.name} -o model.onnx) and pass the .onnx")  # fmt: skip


def file_sha256(path) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def export_in_sync(ckpt_path) -> Path | None:
    """The ``.onnx`` of the same name beside a checkpoint when it was exported from exactly that file
    (its ``source_sha256``), else None — e.g. the shipped model, whose export ships beside it."""
    beside = Path(ckpt_path).with_suffix(".onnx")
    try:
        if is_onnx_path(ckpt_path) or not beside.is_file():
            return None
        a, b = Path(ckpt_path).resolve().stat(), beside.resolve().stat()
        stamp = (a.st_mtime_ns, a.st_size, b.st_mtime_ns, b.st_size)
    except OSError:
        return None
    return beside if _in_sync(str(ckpt_path), str(beside), *stamp) else None


@functools.lru_cache(maxsize=16)
def _in_sync(ckpt: str, onnx: str, *_stamp) -> bool:
    """(cached per file state: ``auto`` and the loader ask in turn)"""
    try:
        return read_onnx_metadata(onnx).get("source_sha256") == file_sha256(ckpt)
    except (ConfigError, OSError):
        return False


def load_runner(path, runtime: str = "auto", threads: int | None = None):
    """(runner, estimator settings, metadata dict) of a checkpoint or an ``.onnx`` export.

    ``runtime``: ``torch`` (a checkpoint in PyTorch), ``onnx`` (an ``.onnx`` file in onnxruntime; a
    checkpoint is exported in memory first where torch is installed; an export beside it made from exactly that
    file — :func:`export_in_sync` — is always used, and without torch nothing else: another export beside it is
    refused, session 53) or ``auto`` (``onnx`` for an ``.onnx`` file, for a checkpoint with an export in sync
    beside it — the shipped model: 13× faster offline than PyTorch here, equal to it to 1e-5 — or when
    torch is absent, else ``torch``). The settings are those :func:`~.checkpoint.load_model` gives for the checkpoint."""
    path = Path(path)
    rt = resolve_runtime(path, runtime)
    if rt == "torch":
        from .checkpoint import load_model

        model, settings, ckpt = load_model(path)
        runner = TorchRunner(model)
        runner.set_threads(threads)
        return runner, settings, ckpt
    if is_onnx_path(path):
        if not path.is_file():
            raise ConfigError(f"{path}: no such model")
        runner = OnnxRunner(path, threads)
    else:
        synced = export_in_sync(path)
        if synced is not None:
            runner = OnnxRunner(synced, threads)
        elif torch_available():
            from .export import export_bytes

            runner = OnnxRunner(export_bytes(path), threads)
        else:
            raise _checkpoint_without_torch(path)
    try:
        settings = estimator_settings(runner.meta)
    except TepinnError as exc:  # (named: a hand-edited export's anchor_config had said nothing of the file)
        if exc.path:
            raise
        raise ConfigError(exc.reason, path) from None
    return runner, settings, runner.meta


def as_runner(model) -> NetworkRunner:
    """A runner for ``model``: a runner as is, a TE-PINN module wrapped in :class:`TorchRunner`."""
    return model if isinstance(model, NetworkRunner) else TorchRunner(model)


def default_onnx_path() -> Path:
    """The shipped model exported to ONNX (beside the checkpoint), used without torch."""
    return Path(__file__).resolve().parents[1] / "assets" / "tepinn_default.onnx"


__all__ = ["NetworkRunner", "TorchRunner", "OnnxRunner", "load_runner", "as_runner", "estimator_settings",
           "model_config_from", "read_onnx_metadata", "resolve_runtime", "torch_available", "RUNTIMES"]
