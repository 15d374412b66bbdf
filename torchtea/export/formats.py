"""The files navigation filters read, written from the axes' :class:`~.terms.AxisTerms`.

A format is one class in :data:`FORMATS`: its name, file name, the sensors it needs, and :meth:`Format.render`.
Kalibr's ``imu.yaml`` (YAML), VINS-Mono/Fusion's and ORB-SLAM3's settings and OpenVINS's ``kalibr_imu_chain.yaml``
(OpenCV FileStorage YAML, ``%YAML:1.0``)
take one number per sensor: the largest axis's, said so in a comment with its 95 % interval, the bare and the
covered value and the cover's factor; the IEEE Std 952 table (CSV) has every axis, and gtsam's preintegration
noise (YAML, and a Python module that sets ``PreintegrationCombinedParams``) a value per axis. Comments carry the convention:
continuous time, a filter at Δt uses σ_d = N/√Δt for the white noise and σ_bd = K·√Δt for the walk.
"""
from __future__ import annotations

import csv
import io

from ..core.registry import Registry
from .terms import IN_FORMATS

__all__ = ["Format", "FORMATS", "register_format", "unregister_format", "sensor_values", "per_axis", "FormatError"]


class FormatError(ValueError):
    """The recording cannot fill the format (a sensor it needs is missing)."""


def _fmt(x: float | None) -> str:
    return "null" if x is None else f"{x:.6e}"


def sensor_values(axes: list, sensor: str, term: str, which: str) -> dict:
    """The format's one number for ``sensor``'s ``term`` (N or K): the largest axis's ``which`` value (bare or
    covered) → ``{"value", "axis", "ci95", "bare", "covered", "factor", "forced_by", "unit"}``."""
    rows = [a for a in axes if a.sensor == sensor]
    if not rows:
        raise FormatError(f"no {sensor} axis")
    pick = max(rows, key=lambda a: getattr(a, which)[term].value)
    num = getattr(pick, which)[term]
    f = pick.factor[term]
    return {"value": num.value, "axis": pick.label, "ci95": num.ci95, "bare": pick.bare[term].value,
            "bare_ci95": pick.bare[term].ci95, "covered": pick.covered[term].value,
            "covered_ci95": pick.covered[term].ci95, "factor": None if f is None else f.value,
            "forced_by": pick.forced_by.get(term), "unit": num.unit,
            "axes": {a.label: getattr(a, which)[term].value for a in rows}}


def _ci(c) -> str:
    return "no interval" if c is None else f"95 % [{c[0]:.4g}, {c[1]:.4g}]"


def _comment(v: dict, which: str) -> list[str]:
    """Comment lines for one field."""
    other = "covered" if which == "bare" else "bare"
    lines = [f"#   {v['unit']}, the largest of the axes ({', '.join(f'{k} {x:.4g}' for k, x in v['axes'].items())}): "
             f"{v['axis']}, {which} value, {_ci(v['ci95'])}",
             f"#   {other}: {v[other]:.4g} ({_ci(v[other + '_ci95'])})"]
    fb = v["forced_by"] or {}
    where = (f", forced at τ {fb['tau_s']:.3g} s by {fb['component']}" if fb.get("component") else
             f", forced at τ {fb['tau_s']:.3g} s" if fb else "")
    if v["factor"] is not None and v["factor"] > 1 + 1e-6:
        lines.append(f"#   the cover raises the bare value × {v['factor']:.3g}{where}")
    elif v["bare"] == 0 and v["covered"] > 0:
        lines.append(f"#   the model has none; the cover needs it{where}")
    return lines


class Format:
    """One file format. ``needs``: the sensors it must have; ``filename``; :meth:`render` writes the text."""

    name = ""
    filename = ""
    needs: tuple = ("accelerometer", "gyroscope")
    #: (sensor, term) → the format's key, in the file's order
    keys: dict = {}
    header = ""

    def check(self, axes: list) -> None:
        have = {a.sensor for a in axes}
        missing = [s for s in self.needs if s not in have]
        if missing:
            raise FormatError(f"{self.name}: the file needs {' and '.join(self.needs)} noise; the recording has no "
                              f"{' or '.join(missing)} channel analysed")

    def fields(self, axes: list, which: str) -> list:
        return [(key, sensor_values(axes, sensor, term, which)) for (sensor, term), key in self.keys.items()]

    def preamble(self, axes: list, meta: dict, which: str) -> list[str]:
        models = "; ".join(f"{a.label}: {a.model}" for a in axes)
        lines = [f"# torchtea export ({self.name}) of {meta.get('recording', '?')}",
                 f"# models fitted per axis: {models}",
                 "# continuous time: N is a white noise density (unit/sqrt(Hz)), K a bias random walk "
                 "(unit/s/sqrt(Hz));",
                 "# a filter at sample time dt uses sigma_d = N/sqrt(dt) for the white noise and "
                 "sigma_bd = K*sqrt(dt) for the bias walk.",
                 f"# values: {which} ('bare': the fitted white noise and random walk; 'covered': the least values "
                 f"whose Allan deviation",
                 f"# covers the fitted model's over tau {axes[0].horizon[0]:g}-{axes[0].horizon[1]:g} s; see "
                 "export.md for what the format leaves out)"]
        for a in axes:
            for c in a.components:
                if c["term"] not in IN_FORMATS:
                    lines.append(f"# not in the format ({a.label}): {c['words']}")
        return lines

    def render(self, axes: list, meta: dict, which: str = "covered") -> str:
        self.check(axes)
        lines = [self.header] if self.header else []
        lines += self.preamble(axes, meta, which)
        lines += self.extra(axes, meta, before=True)
        for key, v in self.fields(axes, which):
            lines += [f"{key}: {_fmt(v['value'])}"] + _comment(v, which)
        lines += self.extra(axes, meta, before=False)
        return "\n".join(lines) + "\n"

    def extra(self, axes: list, meta: dict, before: bool) -> list[str]:
        return []


class Kalibr(Format):
    """Kalibr's IMU configuration (``imu.yaml``: its wiki's "IMU Noise Model" page names the four densities)."""

    name = "kalibr"
    filename = "imu.yaml"
    keys = {("accelerometer", "N"): "accelerometer_noise_density", ("accelerometer", "K"): "accelerometer_random_walk",
            ("gyroscope", "N"): "gyroscope_noise_density", ("gyroscope", "K"): "gyroscope_random_walk"}

    def extra(self, axes, meta, before):
        if not before:
            return []
        return [f"rostopic: {meta.get('topic') or '/imu0'}",
                f"update_rate: {1.0 / axes[0].h:.6g}  # Hz, the recording's sample rate"]


class Vins(Format):
    """VINS-Mono / VINS-Fusion settings (OpenCV FileStorage YAML): ``acc_n``, ``gyr_n``, ``acc_w``, ``gyr_w``."""

    name = "vins"
    filename = "vins_imu.yaml"
    header = "%YAML:1.0"
    keys = {("accelerometer", "N"): "acc_n", ("gyroscope", "N"): "gyr_n", ("accelerometer", "K"): "acc_w",
            ("gyroscope", "K"): "gyr_w"}

    def extra(self, axes, meta, before):
        if before:
            return ["# the fields take Kalibr's continuous-time numbers (how VINS discretises them: VINS-Mono issue "
                    "#102); VINS's example settings inflate them",
                    "# by hand for what the white noise + random walk leaves out, which the covered values do with a "
                    "reason (export.md)"]
        return []


class OrbSlam3(Format):
    """ORB-SLAM3 settings (OpenCV FileStorage YAML): ``IMU.NoiseGyro``, ``IMU.NoiseAcc``, ``IMU.GyroWalk``,
    ``IMU.AccWalk``, ``IMU.Frequency`` (continuous-time densities; ORB-SLAM3 multiplies the noise by √f and
    divides the walk by it)."""

    name = "orbslam3"
    filename = "orbslam3_imu.yaml"
    header = "%YAML:1.0"
    keys = {("gyroscope", "N"): "IMU.NoiseGyro", ("accelerometer", "N"): "IMU.NoiseAcc",
            ("gyroscope", "K"): "IMU.GyroWalk", ("accelerometer", "K"): "IMU.AccWalk"}

    def extra(self, axes, meta, before):
        if before:
            return []
        return [f"IMU.Frequency: {1.0 / axes[0].h:.6g}", "#   Hz, the recording's sample rate"]


class OpenVins(Format):
    """OpenVINS's IMU file (``kalibr_imu_chain.yaml``): Kalibr's four continuous-time densities, but under an ``imu0``
    node of an OpenCV FileStorage file (``%YAML:1.0``), which is how OpenVINS reads them (``parse_external`` of
    ``imu0``'s ``gyroscope_noise_density`` … in its ``VioManagerOptions``); a Kalibr ``imu.yaml`` with the keys at the
    top is not read. The node also carries the IMU intrinsics OpenVINS reads beside them, written as the identity
    (no misalignment or scale error, no g-sensitivity): torchtea estimates noise, not intrinsics."""

    name = "openvins"
    filename = "kalibr_imu_chain.yaml"
    header = "%YAML:1.0"
    keys = Kalibr.keys

    def render(self, axes: list, meta: dict, which: str = "covered") -> str:
        self.check(axes)
        eye = lambda n: [f"    - [{', '.join('1.0' if i == j else '0.0' for j in range(n))}]" for i in range(n)]  # noqa: E731
        lines = [self.header, *self.preamble(axes, meta, which), "",
                 "imu0:", "  T_i_b:", *eye(4)]
        for key, v in self.fields(axes, which):
            lines += [f"  {key}: {_fmt(v['value'])}"] + _comment(v, which)
        lines += [f"  rostopic: {meta.get('topic') or '/imu0'}", "  time_offset: 0.0",
                  f"  update_rate: {1.0 / axes[0].h:.6g}  # Hz, the recording's sample rate",
                  "# the IMU intrinsics OpenVINS reads with the noise: identity (torchtea does not estimate them; "
                  "keep your own if you have them)",
                  '  model: "kalibr"']
        for name, n, zero in (("Tw", 3, False), ("R_IMUtoGYRO", 3, False), ("Ta", 3, False),
                              ("R_IMUtoACC", 3, False), ("Tg", 3, True)):
            rows = [f"    - [{', '.join('0.0' for _ in range(n))}]" for _ in range(n)] if zero else eye(n)
            lines += [f"  {name}:", *rows]
        return "\n".join(lines) + "\n"


class Ieee952(Format):
    """The IEEE Std 952 coefficient table, one row per axis and coefficient (CSV): Q, N, B, K, R with units,
    95 % intervals and how each was made."""

    name = "ieee952"
    filename = "ieee952.csv"
    needs = ()
    columns = ("axis", "sensor", "coefficient", "value", "ci95_low", "ci95_high", "unit", "how")

    def render(self, axes: list, meta: dict, which: str = "covered") -> str:
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(self.columns)
        for a in axes:
            for sym in ("Q", "N", "B", "K", "R"):
                num = a.ieee[sym]
                c = num.ci95
                w.writerow([a.label, a.sensor, sym, "" if num.value is None else f"{num.value:.6e}",
                            "" if c is None else f"{c[0]:.6e}", "" if c is None else f"{c[1]:.6e}", num.unit, num.how])
        return out.getvalue()


def per_axis(axes: list, sensor: str, term: str, which: str) -> tuple[list, list]:
    """``sensor``'s ``term`` (N or K, ``which`` value) on its x, y, z axes, and what stood in for an axis the recording
    lacks (the largest of those it has, said in ``notes``)."""
    rows = {a.label[-1]: a for a in axes if a.sensor == sensor}
    if not rows:
        raise FormatError(f"no {sensor} axis")
    largest = max(getattr(a, which)[term].value for a in rows.values())
    values, notes = [], []
    for ax in "xyz":
        if ax in rows:
            values.append(getattr(rows[ax], which)[term].value)
        else:
            values.append(largest)
            notes.append(f"{sensor} {ax}: not in the recording; the largest of its other axes stands in")
    if term == "K" and not all(values):
        notes.append(f"{sensor}: K = 0 on an axis (its model has no random walk): a bias covariance of 0 is singular "
                     "for a filter — use --values covered, or give it a floor of your own")
    return values, notes


class GtsamYaml(Format):
    """gtsam's IMU preintegration noise (``PreintegrationCombinedParams``) as YAML: per axis x, y, z, the continuous-
    time densities gtsam's covariances are the squares of — ``setAccelerometerCovariance(diag(N_a²))``,
    ``setGyroscopeCovariance(diag(N_g²))``, ``setBiasAccCovariance(diag(K_a²))``, ``setBiasOmegaCovariance(diag(K_g²))``
    (gtsam's examples and its ImuFactor documentation take them in continuous time)."""

    name = "gtsam"
    filename = "gtsam_imu.yaml"
    keys = {("accelerometer", "N"): "accelerometer_noise_density", ("gyroscope", "N"): "gyroscope_noise_density",
            ("accelerometer", "K"): "accelerometer_random_walk", ("gyroscope", "K"): "gyroscope_random_walk"}

    def render(self, axes: list, meta: dict, which: str = "covered") -> str:
        self.check(axes)
        lines = self.preamble(axes, meta, which)
        lines.append("# gtsam: PreintegrationCombinedParams covariances = diag(value²) per axis x, y, z; the "
                     "integration covariance is not the IMU's (set it yourself)")
        for (sensor, term), key in self.keys.items():
            values, notes = per_axis(axes, sensor, term, which)
            unit = next(getattr(a, which)[term].unit for a in axes if a.sensor == sensor)
            lines.append(f"{key}: [{', '.join(_fmt(v) for v in values)}]  # {unit}, x y z")
            lines += [f"#   {n}" for n in notes]
        lines.append(f"update_rate: {1.0 / axes[0].h:.6g}  # Hz, the recording's sample rate")
        return "\n".join(lines) + "\n"


class GtsamPython(GtsamYaml):
    """The same numbers as a Python module whose ``preintegration_params()`` returns gtsam's
    ``PreintegrationCombinedParams`` with them set (gtsam#213: what users write by hand)."""

    name = "gtsam-python"
    filename = "gtsam_imu.py"

    def render(self, axes: list, meta: dict, which: str = "covered") -> str:
        self.check(axes)
        lines = ['"""IMU noise for gtsam\'s preintegration, written by torchtea export."""']
        lines += self.preamble(axes, meta, which)
        lines += ["import numpy as np", "", ""]
        names = {}
        for (sensor, term), key in self.keys.items():
            values, notes = per_axis(axes, sensor, term, which)
            unit = next(getattr(a, which)[term].unit for a in axes if a.sensor == sensor)
            names[(sensor, term)] = key.upper()
            lines += [f"#   {n}" for n in notes]
            lines.append(f"{key.upper()} = ({', '.join(repr(float(v)) for v in values)})  # {unit}, x y z")
        lines += [f"UPDATE_RATE_HZ = {1.0 / axes[0].h!r}", "", "",
                  "def preintegration_params(gravity=9.81, integration_sigma=0.0):",
                  '    """gtsam.PreintegrationCombinedParams (z up, gravity in m/s²) with this IMU\'s noise: each '
                  'covariance diag(value²);',
                  '    ``integration_sigma``: the integration covariance\'s σ, not the IMU\'s (0 by default)."""',
                  "    import gtsam", "",
                  "    p = gtsam.PreintegrationCombinedParams.MakeSharedU(gravity)",
                  f"    p.setAccelerometerCovariance(np.diag(np.square({names[('accelerometer', 'N')]})))",
                  f"    p.setGyroscopeCovariance(np.diag(np.square({names[('gyroscope', 'N')]})))",
                  f"    p.setBiasAccCovariance(np.diag(np.square({names[('accelerometer', 'K')]})))",
                  f"    p.setBiasOmegaCovariance(np.diag(np.square({names[('gyroscope', 'K')]})))",
                  "    p.setIntegrationCovariance(np.eye(3) * integration_sigma ** 2)",
                  "    return p"]
        return "\n".join(lines) + "\n"


#: The formats by name (a user's: :func:`register_format`; the rule of :class:`~torchtea.core.registry.Registry` for
#: registering again and unregistering).
FORMATS = Registry("format")


def register_format(cls: type, *, replace: bool = False) -> type:
    """Class decorator: the :class:`Format` subclass becomes the export format of its ``name`` (a name that has a
    format already, a built-in one's included, needs ``replace=True``: ``register_format(Mine, replace=True)``)."""
    if not (isinstance(cls, type) and issubclass(cls, Format)):
        raise TypeError(f"register_format takes a Format subclass, got {cls!r}")
    if not cls.name or not cls.filename:
        raise ValueError(f"{cls.__name__}: a format needs a name and a filename")
    FORMATS.add(cls.name, cls(), replace=replace)
    return cls


def unregister_format(name: str) -> None:
    """Remove a user's format (where it had replaced a built-in one of that name, the built-in one is back)."""
    FORMATS.remove(name)


for _cls in (Kalibr, Vins, OrbSlam3, Ieee952, GtsamYaml, GtsamPython, OpenVins):
    register_format(_cls)
FORMATS.seal()
