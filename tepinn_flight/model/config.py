"""TE-PINN model configuration: one frozen dataclass, every paper component switchable; the
defaults are the shipped model's (``assets/tepinn_default.pt``)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from ..config import check_choice, check_range
from ..errors import ConfigError


ENCODERS = ("transformer", "lstm", "mlp")
#: the centripetal inputs c_jk are given per this speed (≈ g at 0.3 rad/s); the network's features
#: and their compiled form (window_features.py) both read it here
CEN_FEATURE_M_S = 30.0


@dataclass(frozen=True)
class ModelConfig:
    # --- tokens: IMU samples averaged onto a fixed time grid, so one model serves 25–400 Hz logs
    token_rate_hz: float = 25.0  # tokens per second
    window_tokens: int = 80  # K tokens per window (window length K / token_rate_hz seconds)
    use_mag: bool = False  # 9-D mode: magnetometer channels as inputs (and heading from them)

    # --- encoder
    encoder: Literal["transformer", "lstm", "mlp"] = "transformer"
    d_model: int = 48
    n_heads: int = 4
    n_layers: int = 2
    d_ff: int = 96
    dropout: float = 0.0
    pe_min_wavelength_s: float = 0.04  # timestamp positional encoding wavelengths (seconds)
    pe_max_wavelength_s: float = 16.0

    # --- physics-informed parts (each switchable for the ablation)
    physics: bool = True  # sensor model + RK4-propagated inputs/outputs + physics losses
    correction_layer: bool = True  # yaw := 0 on the output (the paper's 6-D attitude correction)
    uncertainty: bool = True  # σ head trained with a Gaussian NLL on the tilt error
    clip_aware: bool = True  # RK4-rotated inputs across a saturated sample are marked untrusted
    # a saturated gyro reads less than the true rate: clipped tokens' rates are scaled by a learned
    # (1 + κ·clipped fraction), κ ∈ [0, declip_max], starting at 1 (a global sensor-model parameter)
    declip: bool = True
    declip_max: float = 2.0
    # the physics baseline's tilt is a learned softmax pooling of the RK4-rotated specific forces
    # (logits from each token's encoding; starts as their plain mean) instead of their trusted mean
    learned_pooling: bool = True
    # (together they cut the error on flights whose gyro saturates through flips by a third, at a
    # cost on fixed wing; checkpoints written before they existed are read with both off:
    # model/checkpoint.py)
    # velocity-aided gravity (transport theorem): the specific force of token j is compensated by
    # the centripetal acceleration ω_j × v of a body-frame velocity v the network estimates per
    # window (an aircraft flies along its x axis at tens of m/s: in a turn or a loop, ω × v, not
    # gravity, dominates what the accelerometer reads); inputs gain R_{K←j}(ω_j × e_k), k = x, y, z
    # (needs physics: models without it, the LSTM baseline, set it false)
    centripetal: bool = True
    # ... and the body velocity may change linearly over the window, v(t) = v̂ + (t − t_K)·â (a dive
    # or a pull-up changes the speed by tens of m/s in seconds): the compensation adds ω × â·(t − t_K) + â
    centripetal_rate: bool = True
    # plausible limits of the learned global sensor model (tanh-bounded; 0: unbounded): scale and
    # misalignment (fraction), gyro bias (rad/s), accelerometer bias (m/s²)
    sensor_scale_max: float = 0.05
    sensor_gyro_bias_max_rad_s: float = 0.05
    sensor_accel_bias_max_m_s2: float = 0.5

    def __post_init__(self):
        # every numeric field within its range (finite): one line naming the key and the range
        check_range("token_rate_hz", self.token_rate_hz, 0, 10000, lo_open=True)
        check_range("window_tokens", self.window_tokens, 2, 100000)
        for name in ("d_model", "n_heads", "n_layers", "d_ff"):
            check_range(name, getattr(self, name), 1, 100000)
        check_range("dropout", self.dropout, 0, 1, hi_open=True)
        check_range("pe_min_wavelength_s", self.pe_min_wavelength_s, 0, None, lo_open=True)
        check_range("pe_max_wavelength_s", self.pe_max_wavelength_s, self.pe_min_wavelength_s, None)
        check_range("declip_max", self.declip_max, 1, 1000, lo_open=True)  # κ starts at 1
        check_choice("encoder", self.encoder, ENCODERS)
        if self.encoder == "transformer" and self.d_model % self.n_heads:
            raise ConfigError("d_model must be a multiple of n_heads")
        if self.centripetal_rate and not self.centripetal:
            raise ConfigError("centripetal_rate needs centripetal = true")
        if self.centripetal and not self.physics:
            raise ConfigError("centripetal needs physics = true (it compensates the RK4-rotated specific forces)")
        # the sensor limits (0: unbounded)
        check_range("sensor_scale_max", self.sensor_scale_max, 0, 1)
        check_range("sensor_gyro_bias_max_rad_s", self.sensor_gyro_bias_max_rad_s, 0, 100)
        check_range("sensor_accel_bias_max_m_s2", self.sensor_accel_bias_max_m_s2, 0, 1000)

    @property
    def variant(self) -> str:
        """Short name used in reports: ``tepinn``, ``lstm`` (the paper's DL baseline: LSTM, no
        physics), or the ablation it is (``tepinn-nophysics``, ``lstm-physics``, ...)."""
        if self.encoder == "lstm":
            name = "lstm-physics" if self.physics else "lstm"
        elif self.encoder == "mlp":
            name = "tepinn-notransformer" if self.physics else "mlp"
        else:
            name = "tepinn" if self.physics else "tepinn-nophysics"
        if not self.correction_layer:
            name += "-nocorrection"
        if not self.uncertainty:
            name += "-nouncertainty"
        return name

    @property
    def window_s(self) -> float:
        return self.window_tokens / self.token_rate_hz

    @property
    def n_inputs(self) -> int:
        """Channels per token given to the encoder."""
        n = 6 + 2  # ω, a, log sample count, clipped fraction
        if self.physics:
            n += 3  # corrected specific force rotated into the window's last body frame (RK4)
            if self.clip_aware:
                n += 1  # 1 where that rotation crosses no saturated sample, else 0
            if self.centripetal:
                n += 9  # ω_c × e_k (k = x, y, z) rotated into the last body frame, per m/s of v
        if self.use_mag:
            n += 3
        return n
