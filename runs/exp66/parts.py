"""Where the agile quad's chain spends its CPU outside the compiled loop (60-s flight, best of 5)."""
import time
import numpy as np
if __name__ == "__main__":
    import tepinn_flight.sim.flight as fl
    from tepinn_flight.sim.simulate import simulate_record, record_from_truth, resolve_sensor, sensor_rng
    from tepinn_flight.sim.sensors import apply_sensors
    from tepinn_flight.sim.vibration import motor_vibration
    from tepinn_flight.quat import quat_from_euler_zyx
    simulate_record("agile_quad", 5.0, 400.0, 1)
    tr = fl.fly("agile_quad", 60.0, 400.0, seed=1)
    cfg = resolve_sensor()
    def best(fn, n=7):
        ts = []
        for _ in range(n):
            t = time.process_time(); fn(); ts.append(time.process_time() - t)
        return min(ts) * 1e3
    print(f"apply_sensors {best(lambda: apply_sensors(tr, cfg, sensor_rng(1))):.2f} ms")
    print(f"record_from_truth (incl. sensors) {best(lambda: record_from_truth(tr, cfg, 1)):.2f} ms")
    rec = record_from_truth(tr, cfg, 1)
    print(f"validate {best(rec.validate):.2f} ms")
    n = len(tr.t_s)
    e = np.random.default_rng(0).normal(size=(n, 3))
    print(f"quat_from_euler_zyx {best(lambda: quat_from_euler_zyx(e[:,0], e[:,1], e[:,2])):.2f} ms")
    hz = np.abs(np.random.default_rng(1).normal(150, 20, (n, 4)))
    print(f"motor_vibration {best(lambda: motor_vibration(hz, np.ones(n), 0.0025, np.random.default_rng(2))):.2f} ms")
    print(f"fly {best(lambda: fl.fly('agile_quad', 60.0, 400.0, seed=1), 5):.2f} ms")
