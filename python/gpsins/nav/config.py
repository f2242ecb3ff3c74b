"""The filter's configuration language: presets, TOML tables and --set overrides, their checks, and
their conversion to the core's InsConfig (the Allan coefficients to process noise, ``core_config``).

A configuration is a TOML table whose keys are the core's `InsConfig` names
(units in the names), plus a few conveniences:

- ``preset = "default" | "report2005"`` starts from a bundled preset
  (``gpsins/nav/presets/*.toml``); the file's own keys then override it.
- ``*_deg`` keys (``attitude_sigma_deg``, ``initial_yaw_deg``, ``heading_sigma_deg``)
  are converted to the radian fields.
- ``[imu_noise]`` holds the IMU's Allan coefficients (what ``gpsins allan``
  reports, or what the simulator drew): white noise N gives the continuous
  density V = N^2; bias instability B and rate random walk K give a random-walk
  bias (see ``bias_models``). A Gauss-Markov process with stationary sigma s has
  an Allan-deviation peak of 0.617 s (not the tuning notes' 0.437 s: that is 0.437 q_c sqrt(T) of
  the driving noise q_c = s sqrt(2/T)), so s = 0.664 B / 0.617
  matches the flat floor 0.664 B; its short-term wander 2 s^2 / T, with T =
  ``bias_tau_s``, plus K^2 drives the random walk. That random walk reaches the
  floor only at averaging times near T, so B also adds a white density to the
  process noise (``*_flicker_white_*``, see ``flicker_white_var``); N itself stays
  what the standstill detector and the zero-rate update use.
- ``gyro_bias_residual_rad_per_s`` / ``accel_bias_residual_mps2``: turn-on bias
  left after calibration; P0 of the bias states is this plus the process spread.
- ``platform = "vehicle" | "handheld"``: a vehicle's heading is its course over ground, taken at
  ``heading_min_speed_mps``, or slower once a measured velocity's course sigma (sigma_v / speed)
  is at most ``heading_max_course_sigma_deg``; a handheld device's heading is searched over the first
  ``heading_search_s`` seconds of fixes (``search_heading``). Replay sets it from the data
  set's ``[vehicle] kind`` (car: vehicle, with the non-holonomic constraint).
- ``[gyro_bias]`` / ``[accel_bias]``: explicit bias models (``model`` =
  random_walk | gauss_markov | constant) override what [imu_noise] gives.

Vector fields take three numbers or one (used for every axis). Unknown keys are
errors naming the source and the key.
"""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from pathlib import Path

import numpy as np

from .. import _core

PRESETS = ("default", "report2005")
UPDATE_CHECKS = ("chi_square", "attitude_correction", "both", "none")

GM_PEAK_PER_SIGMA = 0.617  # ADEV peak of a Gauss-Markov process / its stationary sigma
FLAT_PER_B = 0.664  # ADEV floor of bias instability B

_DEGREE_KEYS = {"attitude_sigma_deg": "attitude_sigma_rad", "initial_yaw_deg": "initial_yaw_rad",
                "heading_sigma_deg": "heading_sigma_rad",
                "heading_max_course_sigma_deg": "heading_max_course_sigma_rad",
                "gyro_range_deg_per_s": "gyro_range_rad_per_s",
                "max_attitude_correction_deg": "max_attitude_correction_rad",
                "pseudorange_elevation_mask_deg": "pseudorange_elevation_mask_rad",
                "body_to_vehicle_ypr_deg": "body_to_vehicle_ypr_rad"}
# Keys for replay's steps before the run (the platform, the fits from the recording), not the core's.
_REPLAY_KEYS = ("preset", "mode", "platform", "heading_search_s", "fit_noise", "estimate_mounting",
                "lever_arm_sigma_m")
_EXTRA_KEYS = {"imu_noise", "gyro_bias_residual_rad_per_s", "accel_bias_residual_mps2", *_REPLAY_KEYS}
PLATFORMS = ("vehicle", "handheld")
# What a platform changes from the preset unless the configuration says otherwise. A handheld device's
# gait (steps at about 2 Hz, the hand's swing) is motion its MEMS noise figures do not cover: against
# centimetre RTK fixes the innovations run at several times their predicted sigma for seconds on end
# (the walk: fix NIS medians 15-67), so a chi-square gate rejects good fixes until the GNSS reset; it
# is off there (measured on the walk: drift RMS 5.6 m with it, 1.3 m without).
PLATFORM_DEFAULTS = {"vehicle": {}, "handheld": {"gate_probability": 0.0}}
_NOISE_KEYS = {"gyro_arw_rad_per_sqrt_s", "gyro_bias_instability_rad_per_s", "gyro_rrw_rad_per_s_sqrt_s",
               "accel_vrw_mps_per_sqrt_s", "accel_bias_instability_mps2", "accel_rrw_mps2_per_sqrt_s", "bias_tau_s"}
_BIAS_KEYS = {"model", "random_walk_per_sqrt_s", "gm_sigma", "gm_tau_s"}


class ConfigError(ValueError):
    pass


def _core_fields() -> set[str]:
    return {k for k in dir(_core.InsConfig()) if not k.startswith("_")}


def _preset(name: str) -> dict:
    if name not in PRESETS:
        raise ConfigError(f"unknown preset '{name}' (known: {', '.join(PRESETS)})")
    text = resources.files(__package__).joinpath("presets", f"{name}.toml").read_text("utf-8")
    return tomllib.loads(text)


def merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
        # A value given in radians replaces the preset's degrees (and the other way round).
        twin = _DEGREE_KEYS.get(k) or next((d for d, r in _DEGREE_KEYS.items() if r == k), None)
        if twin and twin in out and twin not in over:
            del out[twin]
    return out


def load_config(source: str | Path | dict | None = None, overrides: dict | None = None) -> dict:
    """The full configuration table: a preset name, a TOML file, or a dict, then overrides.

    A file or dict without ``preset`` starts from ``default``. Overrides (from
    ``parse_overrides``) are checked as ``--set`` so an error names them.
    """
    if source is None:
        data, where = {}, "<defaults>"
    elif isinstance(source, dict):
        data, where = dict(source), "<dict>"
    elif str(source) in PRESETS and not Path(str(source)).suffix:
        data, where = {"preset": str(source)}, f"preset {source}"
    else:
        path = Path(source)
        if not path.is_file():
            what = "is a directory" if path.is_dir() else "no such file"
            raise ConfigError(f"{path}: {what}; give a TOML file or a preset name ({', '.join(PRESETS)})")
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except OSError as e:
            raise ConfigError(f"{path}: cannot read ({e.strerror})") from e
        except tomllib.TOMLDecodeError as e:
            raise ConfigError(f"{path}: not valid TOML ({e})") from e
        data = data.get("filter", data)
        where = str(path)
    cfg = merge(_preset(data.get("preset", "default")), data)
    cfg["preset"] = data.get("preset", "default")
    check_config(cfg, where)
    if overrides:
        check_config(merge(cfg, overrides), "--set", only=overrides)
        cfg = merge(cfg, overrides)
    given = set(data) | set(overrides or {})
    for key, value in PLATFORM_DEFAULTS.get(cfg.get("platform", "vehicle"), {}).items():
        if key not in given:
            cfg[key] = value
    # A fix-error model is stated whole: a data set (or caller) giving its own correlated part
    # (e.g. an RTK solution's centimetres) does not inherit the preset's fast part on top.
    if "fix_error_gm_sigma_m" in given and "fix_error_fast_sigma_m" not in given:
        cfg["fix_error_fast_sigma_m"] = [0.0, 0.0, 0.0]
    return cfg


def parse_overrides(pairs: list[str]) -> dict:
    """``--set key=value`` items as a nested table: ``imu_noise.bias_tau_s=50`` reaches [imu_noise].

    Values are TOML (numbers, booleans, lists, quoted strings); anything else is
    kept as text, so a type check can name it.
    """
    out: dict = {}
    for item in pairs:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ConfigError(f"--set {item}: expected KEY=VALUE (--set help lists the keys)")
        try:
            parsed = tomllib.loads(f"v = {value.strip()}")["v"]
        except tomllib.TOMLDecodeError:
            parsed = value.strip()
        *tables, leaf = key.split(".")
        node = out
        for t in tables:
            node = node.setdefault(t, {})
            if not isinstance(node, dict):
                raise ConfigError(f"--set {key}: {t} is a value, not a table")
        node[leaf] = parsed
    return out


# Numeric keys that may be negative (offsets, calibrations, angles); the rest are
# spreads, noise densities, times and rates, which may not.
_SIGNED = ("_cal", "lever_arm", "initial_yaw", "gps_time_offset_s", "pseudorange_sigma_m", "body_to_vehicle_ypr",
           "vehicle_point_body_m")
_POSITIVE = {"imu_rate_hz", "heading_search_s", "fix_error_gm_tau_s", "pseudorange_error_gm_tau_s", "nhc_interval_s",
             "fix_uere_m", "bias_tau_s",
             "zero_velocity_sigma_mps", "zero_rate_sigma_rad_per_s",
             "standstill_window_s", "pseudorange_decimation", "gm_tau_s", "standstill_block_s",
             "gyro_range_rad_per_s", "gyro_range_deg_per_s", "accel_range_mps2"}
_RANGES = {"gate_probability": (0.0, 1.0), "pseudorange_elevation_mask_deg": (0.0, 90.0),
           "pseudorange_elevation_mask_rad": (0.0, math.pi / 2)}
_STRINGS = {"preset": PRESETS, "mode": ("loose", "tight"), "platform": PLATFORMS,
            "model": ("random_walk", "gauss_markov", "constant"), "update_check": UPDATE_CHECKS}


def _key_types() -> dict[str, str]:
    """Kind of every top-level key: 'bool', 'int', 'float', 'vec3', 'table', 'str' or 'any'."""
    c = _core.InsConfig()
    kinds = {}
    for k in _core_fields():
        v = getattr(c, k)
        kinds[k] = ("vec3" if isinstance(v, np.ndarray) else "bool" if isinstance(v, bool) else "int"
                    if isinstance(v, int) else "float" if isinstance(v, float) else "str"
                    if hasattr(type(v), "__members__") else "table")  # a pybind11 enum is chosen by name
    for deg, rad in _DEGREE_KEYS.items():
        kinds[deg] = kinds.get(rad, "float")
    kinds.update({"preset": "str", "mode": "str", "platform": "str", "heading_search_s": "float", "fit_noise": "bool",
                  "estimate_mounting": "bool", "lever_arm_sigma_m": "vec3",
                  "imu_noise": "table", "gyro_bias_residual_rad_per_s": "vec3",
                  "accel_bias_residual_mps2": "vec3"})
    for k in _EXTRA_KEYS - set(kinds):
        kinds[k] = "any"  # a convenience key without a declared kind: known, its value unchecked here
    return kinds


def _at(where: str, key: str) -> str:
    return f"--set {key}" if where == "--set" else f"{where}: {key}"


def _check_value(key: str, value, kind: str, where: str) -> None:
    name = key.rsplit(".", 1)[-1]
    if kind == "str":
        if value not in _STRINGS.get(name, (value,)):
            raise ConfigError(f"{_at(where, key)}: got {value!r}; one of {', '.join(_STRINGS[name])}")
        return
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{_at(where, key)}: expected true or false, got {value!r}")
        return
    numbers = value if kind == "vec3" and isinstance(value, list) else [value]
    if kind == "vec3" and len(numbers) not in (1, 3):
        raise ConfigError(f"{_at(where, key)}: expected one number or three (x, y, z), got {len(numbers)}")
    for x in numbers:
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            what = "an integer" if kind == "int" else "a number" if kind == "float" else "one or three numbers"
            raise ConfigError(f"{_at(where, key)}: expected {what}, got {value!r}")
        if kind == "int" and not float(x).is_integer():
            raise ConfigError(f"{_at(where, key)}: expected an integer, got {value!r}")
        if math.isnan(x):
            if name in ("initial_yaw_deg", "initial_yaw_rad"):
                continue  # nan: take the heading from the course over ground
            raise ConfigError(f"{_at(where, key)}: nan is not allowed here")
        lo, hi = _RANGES.get(name, (None, None))
        if lo is not None and not lo <= x <= hi:
            raise ConfigError(f"{_at(where, key)}: {x!r} is outside [{lo:g}, {hi:g}]")
        if any(tag in name for tag in _SIGNED):
            continue
        if name in _POSITIVE and not x > 0:
            raise ConfigError(f"{_at(where, key)}: must be positive, got {x!r}")
        if x < 0:
            raise ConfigError(f"{_at(where, key)}: must not be negative, got {x!r} "
                              "(it is a spread, density, time or rate)")


def _unknown(where: str, keys: list[str], valid: set[str]) -> ConfigError:
    import difflib

    leaf = keys[0].rsplit(".", 1)[-1]
    close = [v for v in sorted(valid) if v.startswith(leaf)][:3] or difflib.get_close_matches(leaf, sorted(valid), n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    return ConfigError(f"{where}: unknown key{'s' if len(keys) > 1 else ''} {', '.join(keys)}{hint}; "
                       f"`gpsins replay SESSION --out X --set help` lists the keys and presets ({', '.join(PRESETS)})")


def check_config(cfg: dict, where: str = "<config>", only: dict | None = None) -> None:
    """Keys known, values of the right type and range; `only` limits the value checks to those keys."""
    kinds = _key_types()
    unknown = sorted(set(cfg) - set(kinds))
    if unknown:
        raise _unknown(where, unknown, set(kinds))
    checked = only if only is not None else cfg
    for key, value in checked.items():
        kind = kinds[key]
        if kind == "table":
            if not isinstance(value, dict):
                raise ConfigError(f"{_at(where, key)}: must be a table ([{key}] in TOML, or --set {key}.KEY=VALUE)")
            valid = _NOISE_KEYS if key == "imu_noise" else _BIAS_KEYS
            bad = sorted(set(value) - valid)
            if bad:
                raise _unknown(where, [f"{key}.{b}" for b in bad], valid)
            for sub, v in value.items():
                _check_value(f"{key}.{sub}", v, "str" if sub == "model" else "vec3", where)
        elif kind != "any":
            _check_value(key, value, kind, where)


def value(cfg: dict, key: str):
    """A key's value in force: the configuration's, else the core's default (a preset need not state
    every key: report2005 has no fix_uere_m)."""
    return cfg[key] if key in cfg else getattr(_core.InsConfig(), key)


def describe_keys(source=None, overrides: dict | None = None, title: str | None = None) -> str:
    """The configuration keys with their values in `source` (default preset) with `overrides` on top
    (a data set's values from its data), and the presets: for --set help."""
    cfg = load_config(source, overrides or {})
    core = _core.InsConfig()
    kinds = _key_types()
    lines = [title] if title else []
    lines += [f"presets: {', '.join(PRESETS)} (--config NAME or a TOML file with preset = NAME)",
              "keys (--set KEY=VALUE; tables with --set TABLE.KEY=VALUE; vectors as [x, y, z] or one number):"]
    for key in sorted(kinds):
        if key == "preset":
            continue
        if kinds[key] == "table":
            for sub in sorted(_NOISE_KEYS if key == "imu_noise" else _BIAS_KEYS):
                value = cfg.get(key, {}).get(sub)
                lines.append(f"  {key}.{sub} = {'(unset)' if value is None else value}")
        else:
            value = cfg.get(key, getattr(core, key, None))  # as value(), without failing on a table-only key
            if isinstance(value, np.ndarray):
                value = value.tolist()
            lines.append(f"  {key} = {value}  [{kinds[key]}]")
    return "\n".join(lines)


def as_vec3(value, key: str) -> np.ndarray:
    v = np.broadcast_to(np.asarray(value, dtype=float), (3,)) if np.ndim(value) <= 1 else None
    if v is None or not np.all(np.isfinite(v)):
        raise ConfigError(f"{key}: expected one or three finite numbers, got {value!r}")
    return v.copy()


def bias_models(noise: dict, tau_s: float) -> tuple[dict, dict, np.ndarray, np.ndarray]:
    """Random-walk bias models from Allan coefficients; also the bias spread they stand for.

    The bias state carries the turn-on residual (constant) plus the drift, so it
    must not decay: a random walk whose driving noise is K^2 plus the short-term
    wander of a Gauss-Markov process standing for the bias instability
    (2 s^2 / T, s = 0.664 B / 0.617, T = bias_tau_s).
    """
    out, sig = [], []
    for b_key, k_key in (("gyro_bias_instability_rad_per_s", "gyro_rrw_rad_per_s_sqrt_s"),
                         ("accel_bias_instability_mps2", "accel_rrw_mps2_per_sqrt_s")):
        s_bi = FLAT_PER_B / GM_PEAK_PER_SIGMA * as_vec3(noise.get(b_key, 0.0), b_key)
        k = as_vec3(noise.get(k_key, 0.0), k_key)
        drive = k ** 2 + 2.0 * s_bi ** 2 / tau_s
        out.append({"model": "random_walk", "random_walk_per_sqrt_s": np.sqrt(drive).tolist()})
        sig.append(s_bi)
    return out[0], out[1], sig[0], sig[1]


def flicker_white_var(b: np.ndarray, tau_s: float) -> np.ndarray:
    """White-noise density (V, per axis) to add so the model covers the bias instability's
    flat Allan floor at every averaging time.

    The random walk above has the Allan variance q t / 3 (q = 2 s^2 / T): it reaches the
    floor F^2 = (0.664 B)^2 only from t = 3 F^2 / q on (about 0.6 T), and the bias wanders
    by that much over shorter times too (flicker has no time scale). A white density V
    adds V / t. The sum V / t + q t / 3 is smallest at t = sqrt(3 V / q), where it equals
    2 sqrt(V q / 3); setting that to F^2 gives V = 3 F^4 / (4 q) = 0.143 T F^2, with
    s = F / 0.617. (The rate random walk K is on both sides and drops out.) Without it
    the attitude was over-confident wherever the bias is not observed (yaw between a
    car's accelerations): on 20 mismatch drives (benchmarks/bench_mismatch.py) the
    attitude's NEES was 4.5 for its 3 states, and 3.6 with it.
    """
    f2 = (FLAT_PER_B * b) ** 2
    return 3.0 * GM_PEAK_PER_SIGMA ** 2 / 8.0 * tau_s * f2


def core_config(cfg: dict) -> _core.InsConfig:
    """The C++ InsConfig for a configuration table (see the module doc)."""
    c = _core.InsConfig()
    fields = _core_fields()
    table = dict(cfg)
    noise = table.pop("imu_noise", None)
    gyro_residual = table.pop("gyro_bias_residual_rad_per_s", None)
    accel_residual = table.pop("accel_bias_residual_mps2", None)
    for k in _REPLAY_KEYS:
        table.pop(k, None)
    for deg, rad in _DEGREE_KEYS.items():
        if deg in table:
            value = table.pop(deg)
            table[rad] = np.radians(value).tolist() if np.ndim(value) else math.radians(value)

    if noise:
        tau = float(noise.get("bias_tau_s", 100.0))
        gb, ab, g_sig, a_sig = bias_models(noise, tau)
        table.setdefault("gyro_arw_rad_per_sqrt_s", noise.get("gyro_arw_rad_per_sqrt_s"))
        table.setdefault("accel_vrw_mps_per_sqrt_s", noise.get("accel_vrw_mps_per_sqrt_s"))
        for white, b_key in (("gyro_flicker_white_rad_per_sqrt_s", "gyro_bias_instability_rad_per_s"),
                             ("accel_flicker_white_mps_per_sqrt_s", "accel_bias_instability_mps2")):
            b = as_vec3(noise.get(b_key, 0.0), b_key)
            table.setdefault(white, np.sqrt(flicker_white_var(b, tau)).tolist())
        table["gyro_bias"] = {**gb, **table.get("gyro_bias", {})}
        table["accel_bias"] = {**ab, **table.get("accel_bias", {})}
        if gyro_residual is not None:
            table.setdefault("gyro_bias_sigma_rad_per_s", np.hypot(as_vec3(gyro_residual, "gyro"), g_sig).tolist())
        if accel_residual is not None:
            table.setdefault("accel_bias_sigma_mps2", np.hypot(as_vec3(accel_residual, "accel"), a_sig).tolist())
    else:
        if gyro_residual is not None:
            table.setdefault("gyro_bias_sigma_rad_per_s", gyro_residual)
        if accel_residual is not None:
            table.setdefault("accel_bias_sigma_mps2", accel_residual)

    for key, value in table.items():
        if key not in fields or value is None:
            continue
        if key == "update_check":
            if value not in UPDATE_CHECKS:
                raise ConfigError(f"update_check: unknown '{value}' ({', '.join(UPDATE_CHECKS)})")
            c.update_check = getattr(_core.UpdateCheck, value)
            continue
        if key in ("gyro_bias", "accel_bias"):
            b = _core.BiasConfig()
            for bk, bv in value.items():
                if bk == "model":
                    try:
                        b.model = getattr(_core.BiasModel, bv)
                    except AttributeError:
                        raise ConfigError(f"[{key}] model: unknown '{bv}' "
                                          "(random_walk, gauss_markov, constant)") from None
                else:
                    setattr(b, bk, as_vec3(bv, f"[{key}] {bk}"))
            setattr(c, key, b)
            continue
        current = getattr(c, key)
        try:
            if isinstance(current, np.ndarray):
                setattr(c, key, as_vec3(value, key))
            elif isinstance(current, bool):
                if not isinstance(value, bool):
                    raise ConfigError(f"{key}: expected true or false, got {value!r}")
                setattr(c, key, value)
            elif isinstance(current, int):
                setattr(c, key, int(value))
            else:
                setattr(c, key, float(value))
        except (TypeError, ValueError) as e:
            if isinstance(e, ConfigError):
                raise
            raise ConfigError(f"{key}: {e}") from e
    return c


def to_toml(cfg: dict) -> str:
    """Write a configuration table back as TOML (scalars, lists, one level of tables)."""
    def val(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, (list, tuple, np.ndarray)):
            return "[" + ", ".join(val(x) for x in np.asarray(v).tolist()) + "]"
        if isinstance(v, float) and math.isnan(v):
            return "nan"
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = [f"{k} = {val(v)}" for k, v in cfg.items() if not isinstance(v, dict)]
    for k, v in cfg.items():
        if isinstance(v, dict):
            lines += ["", f"[{k}]"] + [f"{kk} = {val(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"
