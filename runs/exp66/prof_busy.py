"""cProfile of the offline estimate of the agile tactical F450 (training flight 0008) tiled to 600 s, onnxruntime."""
import cProfile, pstats, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
if __name__ == "__main__":
    from estimate_speed import tiled, head
    from tepinn_flight.ingest import load_record
    from tepinn_flight.model.checkpoint import default_model_path, load_model
    from tepinn_flight.model.runtime import export_in_sync, OnnxRunner
    from tepinn_flight.model.estimate import estimate_record
    rec = load_record(sys.argv[1])
    model, settings, _ = load_model(default_model_path())
    r = OnnxRunner(export_in_sync(default_model_path()))
    r.set_threads(2)
    off = tiled(rec, float(sys.argv[2]))
    estimate_record(r, head(rec, 6.0), settings)
    t0 = time.perf_counter(); estimate_record(r, off, settings); print("plain", time.perf_counter() - t0)
    pr = cProfile.Profile(); pr.enable()
    estimate_record(r, off, settings)
    pr.disable()
    st = pstats.Stats(pr); st.sort_stats("tottime").print_stats(30)
    st.sort_stats("cumtime").print_stats(40)
