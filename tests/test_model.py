"""TE-PINN model: shapes, causality, physics against slow references, training, checkpoints."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from tepinn_flight import quat as Q
from tepinn_flight.model.checkpoint import CheckpointError, load_model, save_checkpoint
from tepinn_flight.model.config import ModelConfig
from tepinn_flight.model.dataset import build_bank, input_statistics, make_batch
from tepinn_flight.model.estimate import estimate_record
from tepinn_flight.model.fusion import FusionConfig, rk4 as rk4_float, tilt_toward
from tepinn_flight.model.losses import LossConfig, TEPINNLoss, tilt_angle
from tepinn_flight.model.network import TEPINN, zero_yaw
from tepinn_flight.model.physics import RigidBody, prefix_products, rk4_delta, rk4_step
from tepinn_flight.model.synthetic import synthetic_record

SMALL = ModelConfig(window_tokens=16, d_model=16, n_heads=2, n_layers=1, d_ff=32)


def random_window(cfg, b=3, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    k = cfg.window_tokens
    gyr = torch.randn(b, k, 3, generator=g, dtype=dtype)
    acc = torch.randn(b, k, 3, generator=g, dtype=dtype) + torch.tensor([0, 0, -9.81], dtype=dtype)
    count = torch.full((b, k), 4.0, dtype=dtype)
    dt = torch.full((b, k), 1 / cfg.token_rate_hz, dtype=dtype)
    t_rel = (torch.arange(k, dtype=dtype) - (k - 1)) / cfg.token_rate_hz
    return gyr, acc, count, t_rel.expand(b, k), dt


@pytest.mark.parametrize("encoder", ["transformer", "lstm", "mlp"])
@pytest.mark.parametrize("physics", [True, False])
def test_shapes_and_unit_norm(encoder, physics):
    cfg = dataclasses.replace(SMALL, encoder=encoder, physics=physics, centripetal=physics, centripetal_rate=physics)
    m = TEPINN(cfg).double()
    out = m(*random_window(cfg))
    assert out["q"].shape == (3, 4) and out["bias"].shape == (3, 3) and out["sigma"].shape == (3,)
    assert out["torque"].shape == (3, cfg.window_tokens, 3)
    np.testing.assert_allclose(out["q"].norm(dim=-1).detach().numpy(), 1.0, atol=1e-12)
    assert torch.all(out["sigma"] > 0)
    # correction layer: yaw is exactly zero
    _, _, yaw = Q.quat_to_euler_zyx(out["q"].detach().numpy())
    np.testing.assert_allclose(yaw, 0.0, atol=1e-12)


def test_zero_yaw_equals_paper_euler_route():
    q = Q.quat_normalize(np.random.default_rng(0).normal(size=(200, 4)))
    np.testing.assert_allclose(
        Q.quat_canonical(zero_yaw(torch.tensor(q)).numpy()), Q.quat_canonical(Q.quat_zero_yaw(q)), atol=1e-9
    )


def test_corrected_output_is_the_zero_yaw_of_baseline_times_correction():
    """The head's shortcut: zero_yaw(gravity_tilt(−f) ⊗ δq) computed as gravity_tilt(δq* turning −f),
    against the written-out route — any δq, any pooled force (upside down and near ±90° pitch too)."""
    from tepinn_flight.model.network import gravity_tilt
    from tepinn_flight.quat import quat_conj, quat_mul, quat_rotate

    rng = np.random.default_rng(3)
    dq = torch.tensor(Q.quat_normalize(rng.normal(size=(5000, 4))))
    f = torch.tensor(rng.normal(size=(5000, 3)) * rng.uniform(0.01, 3.0, (5000, 1)))
    f[:50, 1:] *= 1e-4  # gravity nearly along x
    route = zero_yaw(quat_mul(gravity_tilt(-f), dq))
    short = gravity_tilt(quat_rotate(quat_conj(dq), -f))
    a, b = Q.quat_canonical(short.numpy()), Q.quat_canonical(route.numpy())
    np.testing.assert_allclose(a[50:], b[50:], rtol=0, atol=1e-7)
    np.testing.assert_allclose(a[:50], b[:50], rtol=0, atol=1e-5)  # gravity_tilt's 1e-12 guard under the square root
    assert np.abs(Q.quat_canonical(gravity_tilt(quat_rotate(dq, -f)).numpy()) - Q.quat_canonical(route.numpy())).max() > 0.1  # not δq


def test_estimates_are_causal():
    """Changing samples after time t never changes any output at or before t."""
    torch.manual_seed(0)
    m = TEPINN(SMALL).eval()
    rec = synthetic_record(seed=3, duration_s=8.0, rate_hz=100.0)
    base = estimate_record(m, rec)
    cut = 500
    rec2 = dataclasses.replace(rec, data=rec.data.copy())
    cols = ["gyr_x_rad_s", "gyr_y_rad_s", "acc_z_m_s2"]
    rec2.data.loc[cut + 1 :, cols] += 3.0
    other = estimate_record(m, rec2)
    q0 = base[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    q1 = other[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    assert np.isfinite(q0[cut]).all()
    np.testing.assert_array_equal(q0[: cut + 1], q1[: cut + 1])
    assert not np.allclose(q0[cut + 50 :], q1[cut + 50 :], equal_nan=True)
    # NaN until the first window is full
    first = np.flatnonzero(np.isfinite(q0[:, 0]))[0]
    assert rec.t_s[first] >= (SMALL.window_tokens - 1) / SMALL.token_rate_hz - 1e-9


def test_rk4_exact_for_constant_rate():
    w = torch.tensor([[0.3, -1.1, 2.5]], dtype=torch.float64)
    q = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64)
    dt = torch.tensor([0.0025], dtype=torch.float64)
    for _ in range(400):  # 1 s at 400 Hz
        q = rk4_step(q, w, w, dt)
    exact = Q.quat_from_rotvec(w.numpy()[0] * 1.0)
    np.testing.assert_allclose(Q.quat_canonical(q.numpy()[0]), Q.quat_canonical(exact), atol=1e-11)
    # the float path of the fusion agrees with the torch path
    qf = (1.0, 0.0, 0.0, 0.0)
    for _ in range(400):
        qf = rk4_float(qf, tuple(w[0].tolist()), tuple(w[0].tolist()), 0.0025)
    np.testing.assert_allclose(Q.quat_canonical(np.array(qf)), Q.quat_canonical(exact), atol=1e-11)


def test_rk4_delta_closed_form_is_rk4_step_from_identity():
    # the closed form (a polynomial in φ = |ω| dt / 2) against the generic RK4 step it replaces,
    # from slow to a step of 1.5 rad (where RK4 itself is far from the exact rotation)
    rng = np.random.default_rng(3)
    w = torch.tensor(rng.normal(size=(6, 9, 3)) * np.array([0.01, 1.0, 30.0, 300.0, 0.0, 5.0])[:, None, None])
    dt = torch.tensor(rng.uniform(0.001, 0.01, size=(6, 9)))
    one = torch.zeros(6, 9, 4, dtype=torch.float64)
    one[..., 0] = 1.0
    want = rk4_step(one, w, w, dt)
    np.testing.assert_allclose(rk4_delta(w, dt).numpy(), want.numpy(), atol=1e-14)
    # float32, as the exported network runs it
    np.testing.assert_allclose(rk4_delta(w.float(), dt.float()).numpy(), want.numpy(), atol=2e-7)


def test_torch_quat_mul_is_numpy_quat_mul():
    # the torch path (outer product times the ±1 table) against the numpy path (the written-out
    # sums) and scipy's composition, with broadcasting
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(4)
    p, q = rng.normal(size=(5, 1, 4)), rng.normal(size=(1, 7, 4))
    got = Q.quat_mul(torch.tensor(p), torch.tensor(q)).numpy()
    np.testing.assert_allclose(got, Q.quat_mul(p, q), atol=1e-14)
    pu, qu = p / np.linalg.norm(p, axis=-1, keepdims=True), q / np.linalg.norm(q, axis=-1, keepdims=True)
    pq = Q.quat_mul(torch.tensor(pu), torch.tensor(qu)).numpy().reshape(-1, 4)
    ref = (Rotation.from_quat(np.broadcast_to(pu, (5, 7, 4)).reshape(-1, 4)[:, [1, 2, 3, 0]])
           * Rotation.from_quat(np.broadcast_to(qu, (5, 7, 4)).reshape(-1, 4)[:, [1, 2, 3, 0]])).as_quat()[:, [3, 0, 1, 2]]
    np.testing.assert_allclose(Q.quat_canonical(pq), Q.quat_canonical(ref), atol=1e-12)


def test_torch_quat_rotate_is_numpy_quat_rotate():
    # torch and numpy paths, unit and non-unit quaternions with broadcasting; scipy for the unit ones
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(5)
    q, v = rng.normal(size=(4, 1, 4)), rng.normal(size=(1, 6, 3))
    np.testing.assert_allclose(Q.quat_rotate(torch.tensor(q), torch.tensor(v)).numpy(), Q.quat_rotate(q, v), atol=1e-13)
    qu = q / np.linalg.norm(q, axis=-1, keepdims=True)
    got = Q.quat_rotate(torch.tensor(qu), torch.tensor(v)).numpy()
    ref = Rotation.from_quat(qu[:, 0, [1, 2, 3, 0]]).as_matrix()[:, None] @ v[..., None]
    np.testing.assert_allclose(got, ref[..., 0], atol=1e-13)


def test_prefix_products_match_sequential_reference():
    rng = np.random.default_rng(1)
    dq = Q.quat_from_rotvec(rng.normal(size=(2, 13, 3)))
    got = prefix_products(torch.tensor(dq)).numpy()
    for b in range(2):
        p = np.array([1.0, 0, 0, 0])
        for j in range(13):
            p = Q.quat_mul(p, dq[b, j])
            np.testing.assert_allclose(got[b, j], p, atol=1e-12)


def test_rigid_body_residual_against_float64_loop_and_gradcheck():
    torch.manual_seed(0)
    body = RigidBody().double()
    with torch.no_grad():
        body.L_raw.copy_(torch.tensor([[1.0, 0, 0], [0.2, 0.7, 0], [-0.1, 0.3, 1.4]]))
    w = torch.randn(5, 3, dtype=torch.float64)
    wd = torch.randn(5, 3, dtype=torch.float64)
    tau = torch.randn(5, 3, dtype=torch.float64)
    got = body.residual(w, wd, tau).detach().numpy()
    inertia = body.inertia().detach().numpy()
    for i in range(5):
        iw = [sum(inertia[r][c] * float(w[i, c]) for c in range(3)) for r in range(3)]
        wx = [float(v) for v in w[i]]
        cross = [wx[1] * iw[2] - wx[2] * iw[1], wx[2] * iw[0] - wx[0] * iw[2], wx[0] * iw[1] - wx[1] * iw[0]]
        want = [sum(inertia[r][c] * float(wd[i, c]) for c in range(3)) + cross[r] - float(tau[i, r]) for r in range(3)]
        np.testing.assert_allclose(got[i], want, atol=1e-12)
    assert torch.autograd.gradcheck(lambda a, b, c: body.residual(a, b, c), (w.requires_grad_(), wd.requires_grad_(), tau.requires_grad_()))
    assert torch.autograd.gradcheck(lambda w_, dt_: rk4_delta(w_, dt_), (torch.randn(4, 3, dtype=torch.float64, requires_grad=True), torch.full((4,), 0.04, dtype=torch.float64, requires_grad=True)))


def _train_steps(cfg, loss_cfg, recs, steps, lr=3e-3, seed=0):
    torch.manual_seed(seed)
    bank = build_bank(recs, cfg, (1,), loss_cfg.gyro_pair_tokens)
    m = TEPINN(cfg)
    m.set_normalization(*input_statistics(m.features, bank, cfg))
    loss = TEPINNLoss(loss_cfg, m.body)
    opt = torch.optim.Adam([{"params": list(m.parameters())}, {"params": list(loss.parameters()), "lr": 2e-2}], lr=lr)
    rng = np.random.default_rng(seed)
    first = last = None
    for _ in range(steps):
        e = rng.choice(bank.ends[bank.prev_ok], 32)
        b = make_batch(bank, e, cfg.window_tokens, cfg.correction_layer)
        p = make_batch(bank, e - loss_cfg.gyro_pair_tokens, cfg.window_tokens, cfg.correction_layer)
        both = {k: torch.cat([b[k], p[k]]) for k in ("gyr", "acc", "count", "t_rel", "dt", "mag", "clip")}
        o = m(both["gyr"], both["acc"], both["count"], both["t_rel"], both["dt"], both["mag"], both["clip"])
        total, logs = loss({k: v[:32] for k, v in o.items()}, b, {k: v[32:] for k, v in o.items()})
        opt.zero_grad()
        total.backward()
        opt.step()
        first = first if first is not None else float(logs["L_data"])
        last = float(logs["L_data"])
    return m, first, last


@pytest.mark.slow
def test_tiny_overfit_drives_loss_down_and_inertia_stays_positive_definite():
    recs = [synthetic_record(seed=0, duration_s=10.0, rate_hz=100.0, max_rate_rad_s=2.0)]
    m, first, last = _train_steps(SMALL, LossConfig(), recs, steps=100)
    assert last < 0.4 * first, (first, last)  # starts from the physics baseline, already decent
    eig = torch.linalg.eigvalsh(m.body.inertia().detach())
    assert torch.all(eig > 0)


def test_checkpoint_round_trip_and_corrupt_files(tmp_path):
    torch.manual_seed(0)
    m = TEPINN(SMALL)
    fusion = FusionConfig(process_noise_rad2_s=3e-4)
    save_checkpoint(tmp_path / "m.pt", m, fusion, metrics={"x": 1.0})
    m2, f2, ck = load_model(tmp_path / "m.pt")
    assert f2 == fusion and ck["metrics"] == {"x": 1.0} and ck["model_config"]["window_tokens"] == 16
    x = [t.float() for t in random_window(SMALL, dtype=torch.float32)]
    m.eval()
    torch.testing.assert_close(m(*x)["q"], m2(*x)["q"], rtol=0, atol=0)
    raw = (tmp_path / "m.pt").read_bytes()
    (tmp_path / "cut.pt").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(CheckpointError, match="not a readable checkpoint"):
        load_model(tmp_path / "cut.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not a tepinn-flight checkpoint"):
        load_model(tmp_path / "foreign.pt")
    ck = torch.load(tmp_path / "m.pt", weights_only=True)
    ck["version"] = 99
    torch.save(ck, tmp_path / "future.pt")
    with pytest.raises(CheckpointError, match="unknown checkpoint version 99"):
        load_model(tmp_path / "future.pt")


def test_fusion_tilt_update_moves_gravity_by_the_gain():
    q = tuple(Q.quat_from_euler_zyx(0.2, -0.1, 1.0))
    q_meas = tuple(Q.quat_from_euler_zyx(0.5, 0.3, 0.0))
    full = tilt_toward(q, q_meas, 1.0)
    np.testing.assert_allclose(Q.gravity_body(np.array(full)), Q.gravity_body(np.array(q_meas)), atol=1e-12)
    half = tilt_toward(q, q_meas, 0.5)
    a = tilt_angle(torch.tensor([q]), torch.tensor([q_meas])).item()
    b = tilt_angle(torch.tensor([half], dtype=torch.float64), torch.tensor([q_meas])).item()
    assert abs(b - a / 2) < 1e-9


FEEDBACK = FusionConfig.uncalibrated(bias_states=True, bias_init_sigma_rad_s=0.3, bias_sigma_rad_s=0.3, bias_feedback_windows=3,
                        bias_feedback_deadzone_rad_s=0.002, clip_hold_s=0.1)  # fmt: skip


@pytest.mark.parametrize("fusion", [None, FEEDBACK], ids=["default", "bias-feedback"])
def test_streaming_equals_offline(fusion):
    """The live estimator (one sample at a time) reproduces the offline batched estimate — also with
    bias feedback, where each block of windows sees the gyro minus the fusion's bias of that time
    (a 0.2 rad/s gyro offset makes that bias move)."""
    from tepinn_flight.model.streaming import StreamingEstimator

    torch.manual_seed(1)
    m = TEPINN(SMALL).eval()
    rec = synthetic_record(seed=5, duration_s=4.0, rate_hz=160.0)
    if fusion is not None:
        rec.data[["gyr_x_rad_s", "gyr_y_rad_s"]] += 0.2
    est = estimate_record(m, rec, fusion)
    off = est[["q_est_w", "q_est_x", "q_est_y", "q_est_z"]].to_numpy()
    live = StreamingEstimator(m, fusion, threads=None)
    q_live = np.full_like(off, np.nan)
    b_live = np.full((len(off), 3), np.nan)
    for i, (t, g, a) in enumerate(zip(rec.t_s, rec.gyr_rad_s, rec.acc_m_s2)):
        e = live.push(t, g, a)
        if e.q_nb_wxyz is not None:
            q_live[i] = e.q_nb_wxyz
            b_live[i] = e.gyr_bias_rad_s
    np.testing.assert_array_equal(np.isnan(off[:, 0]), np.isnan(q_live[:, 0]))
    ok = np.isfinite(off[:, 0])
    assert ok.sum() > 100
    np.testing.assert_allclose(Q.quat_canonical(q_live[ok]), Q.quat_canonical(off[ok]), atol=1e-5)
    b_off = est[["gyr_bias_est_x_rad_s", "gyr_bias_est_y_rad_s", "gyr_bias_est_z_rad_s"]].to_numpy()
    np.testing.assert_allclose(b_live[ok], b_off[ok], atol=1e-5)
    if fusion is not None:  # the fusion's bias moved past the dead zone: later blocks saw a corrected gyro
        assert max(abs(v) for v in live.feedback) > 0.001


def test_bias_feedback_subtracts_the_offset_from_the_windows_and_adds_it_back():
    """Windows made with a gyro offset b equal windows of a record whose gyro is b lower, with b
    added to their bias output (the network's bias is a correction to the fed-back one)."""
    from tepinn_flight.model.estimate import network_on_windows
    from tepinn_flight.model.tokens import tokenize_record

    torch.manual_seed(2)
    m = TEPINN(SMALL).double().eval()
    rec = synthetic_record(seed=6, duration_s=3.0, rate_hz=100.0)
    tok = tokenize_record(rec, SMALL.token_rate_hz)
    ends = tok.windows_ending(SMALL.window_tokens)
    off = np.tile([0.05, -0.1, 0.3], (len(ends), 1))
    q1, s1, b1 = network_on_windows(m, tok, ends, off)
    shifted = synthetic_record(seed=6, duration_s=3.0, rate_hz=100.0)
    shifted.data[["gyr_x_rad_s", "gyr_y_rad_s", "gyr_z_rad_s"]] -= off[0]
    q2, s2, b2 = network_on_windows(m, tokenize_record(shifted, SMALL.token_rate_hz), ends)
    np.testing.assert_allclose(q1, q2, atol=1e-9)
    np.testing.assert_allclose(b1, b2 + off, atol=1e-9)
    q0, _, _ = network_on_windows(m, tok, ends)
    assert float(np.abs(q0 - q1).max()) > 1e-4  # the offset does reach the network


def test_trust_after_clipping_closed_form():
    from tepinn_flight.model.network import trust_after_clipping

    clip = torch.zeros(2, 8)
    clip[0, 3] = 0.25  # one saturated token: it and everything before it are untrusted
    clip[1, 7] = 1.0  # saturated last token: only the last token remains (always trusted)
    u = trust_after_clipping(clip)
    assert u[0].tolist() == [0, 0, 0, 0, 1, 1, 1, 1]
    assert u[1].tolist() == [0, 0, 0, 0, 0, 0, 0, 1]
    assert torch.all(trust_after_clipping(torch.zeros(1, 5)) == 1)


def test_physics_baseline_ignores_rotations_across_a_saturated_gyro():
    """With the correction head silenced, the output is the tilt of the trusted tokens' mean
    specific force: tokens before a clipped sample (garbage RK4 rotation) change nothing."""
    cfg = dataclasses.replace(SMALL, window_tokens=12, learned_pooling=False)
    m = TEPINN(cfg).double().eval()
    with torch.no_grad():
        m.head_q.weight.zero_()
    gyr, acc, count, t_rel, dt = random_window(cfg, b=1, seed=3)
    gyr = gyr * 0.0  # no rotation: v_j is the token's own specific force
    clip = torch.zeros(1, 12, dtype=torch.float64)
    clip[0, 4] = 0.5
    q = m(gyr, acc, count, t_rel, dt, None, clip)["q"].detach()
    acc2 = acc.clone()
    acc2[0, :5] += torch.tensor([30.0, -20.0, 5.0], dtype=torch.float64)  # untrusted tokens
    q2 = m(gyr, acc2, count, t_rel, dt, None, clip)["q"].detach()
    torch.testing.assert_close(q, q2, rtol=0, atol=1e-12)
    f = acc[0, 5:].mean(0).numpy()  # closed form: gravity along −(mean trusted specific force)
    np.testing.assert_allclose(Q.gravity_body(q.numpy())[0], -f / np.linalg.norm(f), atol=1e-9)
    # without clipping every token counts, so the same change moves the estimate
    q3 = m(gyr, acc2, count, t_rel, dt, None, torch.zeros_like(clip))["q"].detach()
    assert tilt_angle(q3, q).item() > 0.05


def test_learned_pooling_starts_as_the_plain_mean_and_can_select_tokens():
    """Zero pooling logits: the baseline is the tilt of the plain mean of the rotated specific
    forces (closed form, every token, clipped or not); logits that favour the first five tokens
    move it onto their mean."""
    cfg = dataclasses.replace(SMALL, window_tokens=12, learned_pooling=True, declip=False)
    m = TEPINN(cfg).double().eval()
    with torch.no_grad():
        m.head_q.weight.zero_()
    gyr, acc, count, t_rel, dt = random_window(cfg, b=1, seed=3)
    gyr = gyr * 0.0  # no rotation: v_j is the token's own specific force
    acc = acc.clone()
    acc[0, :5] += torch.tensor([30.0, -20.0, 5.0], dtype=torch.float64)
    clip = torch.zeros(1, 12, dtype=torch.float64)
    clip[0, 4] = 0.5
    q = m(gyr, acc, count, t_rel, dt, None, clip)["q"].detach()
    f = acc[0].mean(0).numpy()
    np.testing.assert_allclose(Q.gravity_body(q.numpy())[0], -f / np.linalg.norm(f), atol=1e-9)
    hook = m.head_pool.register_forward_hook(lambda mod, inp, out: out + torch.tensor(
        [20.0] * 5 + [0.0] * 7, dtype=out.dtype)[None, :, None])  # fmt: skip
    q2 = m(gyr, acc, count, t_rel, dt, None, clip)["q"].detach()
    hook.remove()
    f2 = acc[0, :5].mean(0).numpy()
    np.testing.assert_allclose(Q.gravity_body(q2.numpy())[0], -f2 / np.linalg.norm(f2), atol=1e-6)


def test_centripetal_compensation_recovers_the_bank_of_a_coordinated_turn():
    """Closed form: a level coordinated turn (bank φ, speed V, rate Ω = g·tanφ/V). The gyro reads
    Ω(0, sinφ, cosφ) and the accelerometer −(g/cosφ)·e_z in body axes, so the specific force alone
    says 'level' (error φ). With the body velocity (V, 0, 0) in the velocity head, the physics
    baseline's gravity ω × v − f is the true one; a wrong speed leaves a proportional error."""
    from tepinn_flight.model.network import VEL_SCALE_M_S

    cfg = dataclasses.replace(SMALL, window_tokens=12, learned_pooling=True, centripetal=True, centripetal_rate=False)
    m = TEPINN(cfg).double().eval()
    with torch.no_grad():
        m.head_q.weight.zero_()
    g, phi, v = 9.80665, np.radians(40.0), 55.0
    rate = g * np.tan(phi) / v
    w_b = rate * np.array([0.0, np.sin(phi), np.cos(phi)])
    f_b = np.cross(w_b, [v, 0.0, 0.0]) - g * np.array([0.0, np.sin(phi), np.cos(phi)])  # a − g
    assert np.allclose(f_b, [0.0, 0.0, -g / np.cos(phi)])  # coordinated: no side force
    k = cfg.window_tokens
    gyr = torch.tensor(w_b).expand(1, k, 3).clone()
    acc = torch.tensor(f_b).expand(1, k, 3).clone()
    count = torch.full((1, k), 16.0, dtype=torch.float64)
    dt = torch.full((1, k), 0.04, dtype=torch.float64)
    t_rel = ((torch.arange(k, dtype=torch.float64) - (k - 1)) * 0.04)[None]
    g_true = np.array([0.0, np.sin(phi), np.cos(phi)])

    def tilt_error_deg(speed):
        with torch.no_grad():
            m.head_vel.bias.copy_(torch.tensor([speed / VEL_SCALE_M_S, 0.0, 0.0]))
        out = m(gyr, acc, count, t_rel, dt)
        np.testing.assert_allclose(out["vel"].detach().numpy()[0], [speed, 0, 0], atol=1e-9)
        g_est = Q.gravity_body(out["q"].detach().numpy())[0]
        return np.degrees(np.arccos(np.clip(g_est @ g_true, -1, 1)))

    # uncompensated: the accelerometer says level (to the small turn of −f within the window)
    assert abs(tilt_error_deg(0.0) - 40.0) < 0.05
    assert tilt_error_deg(v) < 1e-5
    assert 10.0 < tilt_error_deg(0.5 * v) < 30.0


def test_declipping_scales_saturated_rates_by_the_learned_gain():
    from tepinn_flight.model.physics import SensorModel

    s = SensorModel(declip_max=2.0)
    assert abs(float(s.clip_gain().detach()) - 1.0) < 1e-6  # starts at κ = 1: true rate twice the range
    w = torch.tensor([[7.0, -1.0, 0.5], [7.0, -1.0, 0.5]])
    out = s.gyro(w, torch.tensor([0.0, 0.6])).detach()
    torch.testing.assert_close(out, torch.tensor([[7.0, -1.0, 0.5], [7.0 * 1.6, -1.6, 0.8]]))
    with torch.no_grad():
        s.k_clip_raw.fill_(50.0)
    assert abs(float(s.clip_gain().detach()) - 2.0) < 1e-6  # bounded by declip_max
    # without declipping (or without clip information) the reading passes unchanged
    torch.testing.assert_close(SensorModel().gyro(w, torch.tensor([0.0, 0.6])), w)
    torch.testing.assert_close(s.gyro(w), w)
    # in the network: a window turning at a constant rate, half its tokens clipped, is rotated
    # by (1 + κ/2)× the reading over those tokens (RK4 of a constant rate is exact)
    cfg = dataclasses.replace(SMALL, window_tokens=12, declip=True)
    m = TEPINN(cfg).double()
    gyr = torch.zeros(1, 12, 3, dtype=torch.float64)
    gyr[..., 0] = 2.0
    clip = torch.full((1, 12), 0.5, dtype=torch.float64)
    dt = torch.full((1, 12), 0.04, dtype=torch.float64)
    w_c = m.sensor.gyro(gyr, clip)
    p_end, _ = m.frames(w_c, dt)
    angle = 2 * torch.atan2(p_end[0, -1, 1:].norm(), p_end[0, -1, 0])
    assert abs(float(angle.detach()) - 2.0 * 1.5 * 11 * 0.04) < 1e-6  # κ is stored in float32


def test_checkpoints_from_before_clip_awareness_still_load(tmp_path):
    torch.manual_seed(0)
    old_cfg = dataclasses.replace(SMALL, clip_aware=False, sensor_scale_max=0.0, sensor_gyro_bias_max_rad_s=0.0,
                                  sensor_accel_bias_max_m_s2=0.0, declip=False, learned_pooling=False,
                                  centripetal=False, centripetal_rate=False)  # fmt: skip
    m = TEPINN(old_cfg)
    with torch.no_grad():
        m.sensor.S_g.fill_(0.3)  # beyond the new limits: must load unbounded, as trained
    save_checkpoint(tmp_path / "old.pt", m, FusionConfig())
    ck = torch.load(tmp_path / "old.pt", weights_only=True)
    for key in ("clip_aware", "sensor_scale_max", "sensor_gyro_bias_max_rad_s", "sensor_accel_bias_max_m_s2",
                "declip", "declip_max", "learned_pooling", "centripetal", "centripetal_rate"):
        del ck["model_config"][key]  # as written by the first release
    for key in ("adaptive_nis", "bias_states", "bias_feedback_windows", "clip_hold_s", "clip_rate_gain"):
        del ck["fusion_config"][key]  # fields the first release did not have
    torch.save(ck, tmp_path / "old.pt")
    m2, f2, _ = load_model(tmp_path / "old.pt")
    assert m2.config == old_cfg and f2.adaptive_nis == 0.0  # not today's defaults (the shipped model)
    # ... filled with what that checkpoint ran with (the low-pass, no feedback), not today's defaults
    assert not f2.bias_states and f2.bias_feedback_windows == 0 and f2.clip_hold_s == 0.0 and f2.clip_rate_gain == 0.0
    assert FusionConfig().bias_states and FusionConfig().bias_feedback_windows == 25
    x = [t.float() for t in random_window(SMALL, dtype=torch.float32)]
    m.eval()
    torch.testing.assert_close(m(*x)["q"], m2(*x)["q"], rtol=0, atol=0)


def _fuse_biased_gyro(adaptive_nis, gyro_bias, sigma=0.05, seconds=30.0):
    """Level vehicle at rest, window estimates = the truth every 40 ms with σ, gyro with an
    unknown constant bias: returns the final tilt error (rad) of the fused output."""
    from tepinn_flight.model.fusion import AttitudeFusion

    f = AttitudeFusion(FusionConfig.uncalibrated(process_noise_rad2_s=1e-6, adaptive_nis=adaptive_nis))
    level = (1.0, 0.0, 0.0, 0.0)
    q = None
    n = int(seconds * 400)
    for i in range(n):
        est = (level, sigma, (0.0, 0.0, 0.0)) if i % 16 == 1 else None
        q, _, _ = f.step(i / 400.0, gyro_bias, est)
    return tilt_angle(torch.tensor([q]), torch.tensor([level])).item()


def test_innovation_adaptive_fusion_bounds_drift_and_is_neutral_on_a_good_gyro():
    bad = (np.radians(8.0), 0.0, 0.0)  # an uncalibrated gyro: 8 °/s the network did not see
    off = _fuse_biased_gyro(0.0, bad)
    on = _fuse_biased_gyro(4.0, bad)
    assert off > np.radians(20.0)  # trusts its propagation and drifts far away
    assert on < np.radians(8.0) and on < 0.25 * off
    good = (0.0, 0.0, 0.0)
    assert _fuse_biased_gyro(4.0, good) == _fuse_biased_gyro(0.0, good)


def test_fusion_propagates_saturated_samples_at_the_declipping_gain():
    """Constant 3 rad/s roll for 0.25 s (first estimate at t=0, no later ones): the propagated roll
    angle is ω·T on unclipped samples and (1 + gain)·ω·T where every sample is flagged clipped."""
    from tepinn_flight.model.fusion import AttitudeFusion

    def roll_after(gain, clipped):
        f = AttitudeFusion(FusionConfig.uncalibrated(clip_rate_gain=gain))
        q = None
        for i in range(101):  # t = 0 … 0.25 s; the estimate (level) arrives with the 2nd sample
            est = ((1.0, 0.0, 0.0, 0.0), 0.01, (0.0, 0.0, 0.0)) if i == 1 else None
            q, _, _ = f.step(i * 0.0025, (3.0, 0.0, 0.0), est, clipped)
        return 2 * np.arctan2(q[1], q[0])

    t_prop = 0.25  # the estimate sets the state at t = 0, then it is propagated to the last sample
    assert abs(roll_after(0.6, False) - 3.0 * t_prop) < 1e-9
    assert abs(roll_after(0.6, True) - 1.6 * 3.0 * t_prop) < 1e-9
    assert abs(roll_after(0.0, True) - 3.0 * t_prop) < 1e-9


def test_sensor_model_limits():
    """tanh limits: the raw value near zero, never beyond the limit, unbounded when off."""
    from tepinn_flight.model.physics import SensorModel

    s = SensorModel(scale_max=0.05, gyro_bias_max_rad_s=0.05, accel_bias_max_m_s2=0.5)
    u = SensorModel()
    w = torch.tensor([[0.0, 0.0, 10.0]])
    with torch.no_grad():
        for m in (s, u):
            m.S_g.fill_(0.0)
            m.S_g[2, 2] = 0.8  # the degenerate solution: −80 % yaw-rate scale
            m.b_a.fill_(1e-4)
    torch.testing.assert_close(u.gyro(w), torch.tensor([[0.0, 0.0, 2.0]]))
    assert abs(float(s.gyro(w).detach()[0, 2]) - 10.0 * (1 - 0.05 * np.tanh(16.0))) < 1e-5
    v = {k: t.detach() for k, t in s.values().items()}
    assert float(v["S_g"].abs().max()) <= 0.05 + 1e-6 and float(v["b_g"].abs().max()) == 0.0
    torch.testing.assert_close(v["b_a"], torch.full((3,), 1e-4), rtol=1e-6, atol=0)  # ≈ raw near 0
    with pytest.raises(Exception, match="'sensor_scale_max' must be finite and in \\[0, 1\\], got -1.0"):
        ModelConfig(sensor_scale_max=-1.0)


def test_baseline_gravity_loss_is_the_robust_angle_to_the_reference_gravity():
    """L_base = mean log(1 + (θ/s)²), θ the angle between the physics baseline's gravity (−f_mean)
    and the reference's: zero when the baseline is right, the closed form for a known tilt, and it
    drives the baseline (here the pooled specific force) toward the reference gravity."""
    s = 0.1
    loss = TEPINNLoss(LossConfig(adaptive=False, base_cauchy_rad=s, lambda_acc=0.0, lambda_dyn=0.0),
                      RigidBody().double())  # fmt: skip
    roll = torch.tensor([0.0, 0.3, -1.2], dtype=torch.float64)
    q_ref = Q.quat_from_euler_zyx(roll, torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64))
    g_ref = Q.gravity_body(q_ref)  # (3, 3) unit down in body axes
    err = torch.tensor([0.0, 0.05, 0.4], dtype=torch.float64)  # baseline tilted by this about body x
    g_base = torch.stack([torch.zeros(3, dtype=torch.float64), torch.cos(roll + err), torch.sin(roll + err)], -1)
    g_base = torch.stack([g_base[:, 0], g_base[:, 2], g_base[:, 1]], -1)  # (0, sin φ, cos φ)
    np.testing.assert_allclose(g_base[0].numpy(), g_ref[0].numpy(), atol=1e-12)
    f_mean = (-1.3 * g_base).requires_grad_()  # any magnitude: only the direction counts
    out = {"q": q_ref, "f_mean": f_mean, "f_spread": torch.zeros(3, dtype=torch.float64),
           "w_c": torch.zeros(3, 4, 3, dtype=torch.float64), "torque": torch.zeros(3, 4, 3, dtype=torch.float64)}  # fmt: skip
    batch = {"q_ref": q_ref, "dt": torch.full((3, 4), 0.04, dtype=torch.float64),
             "has_bias": torch.zeros(3, dtype=torch.bool), "bias_true": torch.zeros(3, 3, dtype=torch.float64)}  # fmt: skip
    total, logs = loss(out, batch)
    expect = float(np.mean(np.log1p((err.numpy() / s) ** 2)))
    assert abs(float(logs["L_base"]) - expect) < 1e-9
    total.backward()
    assert float(f_mean.grad[0].norm()) < 1e-6  # the right baseline is not pushed
    # a small step against the gradient turns the wrong baselines toward the reference
    from tepinn_flight.model.losses import vector_angle

    new = -(f_mean - 1e-3 * f_mean.grad).detach()
    before = vector_angle(-f_mean.detach(), g_ref)
    after = vector_angle(new, g_ref)
    assert bool((after[1:] < before[1:]).all())
    off = TEPINNLoss(LossConfig(adaptive=False, base_cauchy_rad=0.0), RigidBody().double())
    assert "L_base" not in off(out, batch)[1]  # 0: off


@pytest.mark.parametrize("bias_states", [False, True])
def test_fusion_keeps_the_attitude_open_after_saturation_for_the_hold_time(bias_states):
    """At rest, level estimates (σ 0.01 rad) until a burst of 20 clipped samples; estimates after it
    say 30° of roll. With clip_hold_s the covariance stays open after the burst, so the first such
    estimate inside the hold moves the state almost all the way (Kalman gain P/(P+r) ≈ 1); without
    it, the burst's inflation was spent on the estimate made at its end and the gain is about ½.
    With clip_skip_updates the estimates inside the hold are not applied at all."""
    from tepinn_flight.model.fusion import AttitudeFusion

    level = ((1.0, 0.0, 0.0, 0.0), 0.01, (0.0, 0.0, 0.0))
    roll30 = (tuple(Q.quat_from_euler_zyx(np.radians(30.0), 0.0, 0.0)), 0.01, (0.0, 0.0, 0.0))

    def roll_deg_at(t_end, **kw):
        f = AttitudeFusion(FusionConfig.uncalibrated(clip_inflation_rad=0.35, process_noise_rad2_s=1e-6, bias_states=bias_states, **kw))
        dt, q = 0.0025, None
        for i in range(int(round(t_end / dt)) + 1):
            t = i * dt
            clipped = 400 <= i < 416  # 16 samples, t = 1.0 … 1.0375 s
            est = None
            if i % 16 == 1:  # a window estimate every 40 ms (it belongs to the previous sample)
                est = level if i <= 417 else roll30  # the last level one just after the burst
            q, _, _ = f.step(t, (0.0, 0.0, 0.0), est, clipped)
        return np.degrees(2 * np.arctan2(q[1], q[0]))

    # the first 30° estimate is applied at t = 1.0825 s (45 ms after the burst)
    without = roll_deg_at(1.085)
    held = roll_deg_at(1.085, clip_hold_s=0.1)
    assert without < 16.0  # the burst's covariance went into the last level estimate: gain ≈ ½
    assert held > 29.0  # open: the new estimate is taken almost as it is
    skipped = roll_deg_at(1.085, clip_hold_s=0.1, clip_skip_updates=True)
    assert abs(skipped) < 1e-6  # inside the hold nothing is applied; the gyro (zero) holds level
    after = roll_deg_at(1.3, clip_hold_s=0.1, clip_skip_updates=True)
    assert after > 29.0  # the first estimate after the hold meets the open covariance


def test_process_noise_grows_with_the_angle_turned():
    """P grows by q_t·T + q_r·|ω|·T between estimates (closed form for a constant rate): nothing
    from q_r at rest, and the same growth for the same angle whatever the axis."""
    from tepinn_flight.model.fusion import AttitudeFusion

    def p_after(w, q_r, seconds=0.5):
        f = AttitudeFusion(FusionConfig.uncalibrated(process_noise_rad2_s=1e-5, process_noise_rate_rad=q_r))
        for i in range(int(seconds * 400) + 1):
            est = ((1.0, 0.0, 0.0, 0.0), 0.02, (0.0, 0.0, 0.0)) if i == 1 else None
            f.step(i / 400.0, w, est)
        return f.P - 0.02**2  # the estimate at t = 1/400 s left P = r; then 0.5 s of propagation

    assert abs(p_after((0.0, 0.0, 0.0), 1e-3) - 1e-5 * 0.5) < 1e-12
    w = np.array([1.0, -2.0, 2.0])  # |ω| = 3 rad/s: 1.5 rad in 0.5 s
    assert abs(p_after(tuple(w), 1e-3) - (1e-5 * 0.5 + 1e-3 * 1.5)) < 1e-9
    assert abs(p_after((0.0, 3.0, 0.0), 1e-3) - p_after(tuple(w), 1e-3)) < 1e-12
    assert abs(p_after(tuple(w), 0.0) - 1e-5 * 0.5) < 1e-12


def test_centripetal_rate_compensates_a_speed_change_in_a_pull_up():
    """Closed form: a pull-up at pitch rate q with the body velocity (V + â_x·(t − t_K), 0, 0). The
    kinematic acceleration in body axes is ω × v + v̇ = (â_x, 0, −q·v_x); the specific force is that
    minus gravity. With v̂ = (V(t_K), 0, 0) and â = (â_x, 0, 0) in the heads the baseline's gravity
    is exact; the constant-velocity compensation alone leaves an error (the speed change)."""
    from tepinn_flight.model.network import ACC_SCALE_M_S2, VEL_SCALE_M_S

    cfg = dataclasses.replace(SMALL, window_tokens=20, learned_pooling=True, centripetal=True, centripetal_rate=True)
    m = TEPINN(cfg).double().eval()
    with torch.no_grad():
        m.head_q.weight.zero_()
    g, q_rate, v_end, a_x = 9.80665, 0.3, 60.0, -4.0  # decelerating while the nose comes up
    k, dt = cfg.window_tokens, 0.04
    t_end = (np.arange(k) - (k - 1)) * dt  # token ends relative to t_K
    t_mid = t_end - 0.5 * dt
    theta_k = 0.4  # pitch at t_K; pitch(t) = θ_K + q·(t − t_K)
    theta = theta_k + q_rate * t_mid
    vx = v_end + a_x * t_mid
    grav_body = np.stack([-np.sin(theta), np.zeros(k), np.cos(theta)], -1) * g  # gravity in body, per token
    f = np.stack([np.full(k, a_x), np.zeros(k), -q_rate * vx], -1) - grav_body  # specific force
    gyr = torch.tensor(np.tile([0.0, q_rate, 0.0], (1, k, 1)))
    acc = torch.tensor(f[None])
    count = torch.full((1, k), 16.0, dtype=torch.float64)
    dts = torch.full((1, k), dt, dtype=torch.float64)
    t_rel = torch.tensor(t_end[None])
    g_true = np.array([-np.sin(theta_k), 0.0, np.cos(theta_k)])

    def tilt_error_deg(a_head):
        with torch.no_grad():
            m.head_vel.bias.copy_(torch.tensor([v_end / VEL_SCALE_M_S, 0, 0, a_head / ACC_SCALE_M_S2, 0, 0]))
        out = m(gyr, acc, count, t_rel, dts)
        g_est = Q.gravity_body(out["q"].detach().numpy())[0]
        return np.degrees(np.arccos(np.clip(g_est @ g_true, -1, 1)))

    assert tilt_error_deg(a_x) < 0.05  # (token means at token midpoints: not exact, but close)
    assert tilt_error_deg(0.0) > 10.0  # |â|/g ≈ 0.4: the speed change alone tilts it by ~20°
