import time, contextlib
if __name__ == "__main__":
    import tepinn_flight.sim.quad_flight_kernel as k
    import tepinn_flight.sim.flight as fl
    import tepinn_flight.sim.vibration as vib
    acc = {}
    def wrap(mod, name, key):
        orig = getattr(mod, name)
        def w(*a, **kw):
            t = time.process_time(); r = orig(*a, **kw); acc[key] = acc.get(key, 0) + time.process_time() - t; return r
        setattr(mod, name, w)
    wrap(k, "fly_quad", "kernel")
    wrap(fl, "motor_vibration", "vibration")
    wrap(fl, "quat_from_euler_zyx", "quat")
    wrap(fl, "Stepper", "stepper_init")
    wrap(fl, "Sequencer", "seq_init")
    orig_open = fl.open_fdm
    @contextlib.contextmanager
    def op(*a, **kw):
        t = time.process_time()
        with orig_open(*a, **kw) as f:
            acc["open"] = acc.get("open", 0) + time.process_time() - t
            yield f
            t = time.process_time()
        acc["close"] = acc.get("close", 0) + time.process_time() - t
    fl.open_fdm = op
    fl.fly("agile_quad", 5.0, 400.0, seed=3)
    for seed in (1, 1, 1, 1):
        acc.clear()
        t0 = time.process_time(); tr = fl.fly("agile_quad", 60.0, 400.0, seed=seed); tt = time.process_time() - t0
        print(f"fly {tt*1e3:.1f}", " ".join(f"{a} {b*1e3:.1f}" for a, b in acc.items()), f"other {(tt-sum(acc.values()))*1e3:.1f}")
