import time, tempfile, os, cProfile, pstats, sys
import numpy as np
if __name__ == "__main__":
    from tepinn_flight.record import write_record
    from tepinn_flight.sim.simulate import simulate_record, record_from_truth, resolve_sensor, sensor_rng
    from tepinn_flight.sim.flight import fly
    from tepinn_flight.sim.sensors import apply_sensors
    d = tempfile.mkdtemp()
    simulate_record("agile_quad", 5.0, 400.0, 1)
    for r in range(3):
        t0 = time.process_time(); tr = fly("agile_quad", 60.0, 400.0, seed=1)
        t1 = time.process_time(); cfg = resolve_sensor(); out = apply_sensors(tr, cfg, sensor_rng(1))
        t2 = time.process_time(); rec = record_from_truth(tr, cfg, 1)
        t3 = time.process_time(); rec.validate()
        t4 = time.process_time(); write_record(rec, os.path.join(d, "r.parquet"))
        t5 = time.process_time()
        print(f"fly {t1-t0:.4f} sensors {t2-t1:.4f} record_from_truth {t3-t2:.4f} validate {t4-t3:.4f} write {t5-t4:.4f}")
    pr = cProfile.Profile(); pr.enable()
    for i in range(5): rec = record_from_truth(tr, cfg, 1); write_record(rec, os.path.join(d, "r.parquet"))
    pr.disable(); pstats.Stats(pr).sort_stats("tottime").print_stats(30)
