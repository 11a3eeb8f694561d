"""The live monitor on the mock rig: detection delay of a tracker bump (real time) and false
alarms in an hour of a normal session (the fast clock standing in for wall time).

    .venv/bin/python benchmarks/monitor.py [--bumps 20] [--minutes 60] [--hold-s 10]

The rig: ``configs/mock-denso-polaris.yaml`` (mock DENSO arm, mock Polaris Spectra at 60 Hz,
the built-in TMS rig, the paper's noise: 0.05 mm fiducials, 0.05 mm / 0.05° robot
positioning), with the coil's settling swing after every move (``mock.settle``: 0.3 mm,
τ 0.25 s, 4 Hz; the controller does not report it). The calibration: QR36 of 200 simulated
poses of the same rig, ``tmscal solve -o`` (its noise model sets the bound). The monitor runs
through the real drivers and wire protocols (``tmscal.monitor.run_monitor``), default
settings (window 0.25 s, persistence the window + 1 frame, level 1e-6 per still phase,
settle 1 s, latency 0.1 s).

The simulated TMS session: the robot holds the coil and every ``--hold-s`` seconds makes a
small correction as a head-following program would (a random walk of 0.5–3 mm and 0.2–1° per
move, kept within 10 mm and 5° of P0), applied to the mock rig's robot (``SimRig.move_flange``:
the controller reports the new pose at once and the coil swings).

* Detection (``--bumps``, REAL-TIME clock): at a random time of the session (uniform over
  2–8 s after the previous bump was cleared) the tracker is bumped, alternately by 1 mm (a
  random direction) and by 0.5° (about a random axis through the tracker's origin); the
  delay is wall time from the bump to the alarm on the monitor's callback; the bump is then
  undone and the next one waits for the alarm to clear. Goal: ≤ 1 s.
* False alarms (``--minutes``, FAST clock): the session without bumps for that many minutes
  of tracker time (frames / 60 Hz: the rig's time on the fast clock is the tracker's, so the
  swing after a move decays over frames, as it would over wall time, and the monitor's
  durations count frames too). Goal: 0 in one hour.

Prints one line per bump and the summaries; records them (``benchmarks/figures.py``). Takes
about 1 minute per 20 bumps and 5–10 minutes per hour of fast-clock session on 2 cores.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from figures import record

from tmscal.acquisition.devices import Devices, Endpoints
from tmscal.calib.alarm import Rule, simulate_holds
from tmscal.config import load_config
from tmscal.formats.calibfile import read_calibration
from tmscal.geometry import make_pose, matrix_from_rotvec
from tmscal.mocks.launch import start_mock_rig
from tmscal.monitor import Monitor, MonitorEvent, MonitorSettings, run_monitor

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
SETTLE = {"amplitude_mm": 0.3, "tau_s": 0.25, "freq_hz": 4.0}


def calibrate(tmp: Path) -> Path:
    """QR36 of 200 simulated poses of the built-in TMS rig (the paper's noise, seed 3)."""
    from tmscal.session import make_header, records_from_arrays, write_session
    from tmscal.sim import Noise, simulate, tms_rig_truth

    truth, sim = simulate(200, np.random.default_rng(3), noise=Noise(), truth=tms_rig_truth())
    header = make_header(["marker", "probe"], truth=truth.as_dict())
    write_session(tmp / "s.jsonl", header,
                  records_from_arrays(sim["A"], sim["marker"], sim["probe"], sim["commanded"]))
    out = tmp / "calib.yaml"
    subprocess.run([sys.executable, "-m", "tmscal.cli", "solve", str(tmp / "s.jsonl"), "-o",
                    str(out)], check=True, capture_output=True)
    return out


def rig_config(tmp: Path, clock: str, seed: int) -> Path:
    base = CONFIGS / "mock-denso-polaris.yaml"
    data = yaml.safe_load(base.read_text())
    data["tracker"]["tools"] = {k: str((base.parent / v).resolve())
                                for k, v in data["tracker"]["tools"].items()}
    data["mock"].update(clock=clock, seed=seed, settle=SETTLE)
    p = tmp / f"rig-{clock}.yaml"
    p.write_text(yaml.safe_dump(data))
    return p


class Session:
    """The simulated TMS session's robot corrections, every ``hold_s`` of tracker time."""

    def __init__(self, rig, hold_s: float, rng: np.random.Generator) -> None:
        self.rig, self.hold_s, self.rng = rig, hold_s, rng
        self.p0 = rig.reported_flange().copy()
        self.t = np.zeros(3)
        self.w = np.zeros(3)
        self.next = hold_s
        self.moves = 0

    def __call__(self, mon: Monitor) -> None:
        if mon.t_s < self.next:
            return
        self.next += self.hold_s
        for v, lo, hi, cap in ((self.t, 0.5, 3.0, 10.0), (self.w, 0.2, 1.0, 5.0)):
            u = self.rng.standard_normal(3)
            v += u / np.linalg.norm(u) * self.rng.uniform(lo, hi)
            n = np.linalg.norm(v)
            if n > cap:
                v *= cap / n
        self.rig.move_flange(self.p0 @ make_pose(matrix_from_rotvec(np.radians(self.w)),
                                                 self.t))
        self.moves += 1


def _devices(cfg_path: Path, mr) -> Devices:
    host, _, port = mr.endpoints["robot"].partition(":")
    dev = Devices(load_config(cfg_path), "tracker",
                  Endpoints(tracker_port=mr.endpoints["tracker"], robot_host=host,
                            robot_port=int(port) if port else None))
    dev.open()
    return dev


def detection(tmp: Path, cal: Path, bumps: int, hold_s: float, seed: int) -> dict:
    cfg_path = rig_config(tmp, "real", seed)
    rng = np.random.default_rng(seed)
    mr = start_mock_rig(load_config(cfg_path), tracker_transport="tcp", robot_port=0)
    dev = _devices(cfg_path, mr)
    session = Session(mr.rig, hold_s, rng)
    st: dict = {"next": 2.0 + rng.uniform(2, 8), "bump": None, "rows": [], "false": 0,
                "waiting_clear": False}

    def on_frame(mon: Monitor, fr) -> None:
        session(mon)
        if st["bump"] is None and not st["waiting_clear"] and mon.t_s >= st["next"]:
            i = len(st["rows"])
            u = rng.standard_normal(3)
            u /= np.linalg.norm(u)
            kind = "1 mm" if i % 2 == 0 else "0.5°"
            mm, deg = (u * 1.0, np.zeros(3)) if kind == "1 mm" else (np.zeros(3), u * 0.5)
            mr.rig.apply_change("tracker", mm, deg)
            st["bump"] = (kind, mm, deg, time.monotonic(), mon.t_s, mon.since_move_s)
        if st["bump"] is not None and mon.t_s - st["bump"][4] > 10.0:  # missed
            kind, mm, deg, _, t_b, since = st["bump"]
            st["rows"].append((kind, None, since, None, None))
            _undo(mm, deg)

    def _undo(mm, deg) -> None:
        mr.rig.apply_change("tracker", -np.asarray(mm), -np.asarray(deg))
        st["bump"], st["waiting_clear"] = None, True

    def on_event(ev: MonitorEvent) -> None:
        if ev.kind == "alarm":
            if st["bump"] is None:
                st["false"] += 1
                return
            st["alarm"] = (time.monotonic() - st["bump"][3], ev.t_s)
        elif ev.kind == "diagnosis" and st["bump"] is not None and "alarm" in st:
            kind, mm, deg, t0, t_b, since = st["bump"]
            delay, t_alarm = st.pop("alarm")
            named = time.monotonic() - t0
            st["rows"].append((kind, delay, since, named,
                               " or ".join(ev.details.get("candidates") or ["?"])))
            print(f"  bump {len(st['rows']):>3}  tracker {kind:<5} at {t_b:7.2f} s "
                  f"({since:4.1f} s into the hold): alarm after {delay:.3f} s "
                  f"({t_alarm - t_b:.3f} s of tracker time), what moved after {named:.3f} s: "
                  f"{st['rows'][-1][4]}", flush=True)
            _undo(mm, deg)
        elif ev.kind == "clear" and st["waiting_clear"]:
            st["waiting_clear"] = False
            st["next"] = ev.t_s + rng.uniform(2, 8)

    try:
        run_monitor(dev.robot, dev.tracker, read_calibration(cal), MonitorSettings(),
                    on_event=on_event, on_frame=lambda m, f: on_frame(m, f),
                    stop=lambda: len(st["rows"]) >= bumps)
    finally:
        dev.close()
        mr.close()
    return st


def false_alarms(tmp: Path, cal: Path, minutes: float, hold_s: float, seed: int) -> dict:
    cfg_path = rig_config(tmp, "fast", seed)
    mr = start_mock_rig(load_config(cfg_path), tracker_transport="tcp", robot_port=0)
    dev = _devices(cfg_path, mr)
    session = Session(mr.rig, hold_s, np.random.default_rng(seed))
    alarms: list[MonitorEvent] = []
    t0 = time.monotonic()
    frames = int(round(minutes * 60 * dev.tracker.frame_rate_hz))
    try:
        mon = run_monitor(dev.robot, dev.tracker, read_calibration(cal), MonitorSettings(),
                          frames=frames, on_event=lambda e: alarms.append(e)
                          if e.kind == "alarm" else None,
                          on_frame=lambda m, f: session(m))
    finally:
        dev.close()
        mr.close()
    return {"mon": mon, "alarms": alarms, "moves": session.moves,
            "wall_s": time.monotonic() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bumps", type=int, default=20, help="tracker bumps (real time); 0: none")
    ap.add_argument("--minutes", type=float, default=60.0,
                    help="minutes of fast-clock session for the false alarms; 0: none")
    ap.add_argument("--hold-s", type=float, default=10.0,
                    help="seconds between the session's robot corrections")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--sim-holds", type=int, default=2000,
                    help="simulated holds for the rule's false-alarm share (0: none)")
    a = ap.parse_args()
    fig: dict[str, float | int | None] = {}
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        cal = calibrate(tmp)
        if a.bumps:
            print(f"detection: {a.bumps} tracker bumps on the real-time mock rig, a robot "
                  f"correction every {a.hold_s:g} s")
            st = detection(tmp, cal, a.bumps, a.hold_s, a.seed)
            for kind in ("1 mm", "0.5°"):
                rows = [r for r in st["rows"] if r[0] == kind]
                got = [r[1] for r in rows if r[1] is not None]
                named = [r[3] for r in rows if r[3] is not None]
                key = "mm" if kind == "1 mm" else "deg"
                within = sum(1 for x in got if x <= 1.0)
                print(f"  tracker {kind}: {len(got)} of {len(rows)} detected; alarm after "
                      f"median {np.median(got):.2f} s, max {max(got):.2f} s ({within} of "
                      f"{len(rows)} within 1 s); what moved after median "
                      f"{np.median(named):.2f} s, max {max(named):.2f} s; named: "
                      + ", ".join(f"{c} {sum(r[4] == c for r in rows)}"
                                  for c in sorted({str(r[4]) for r in rows})))
                fig.update({f"alarm_{key}_median_s": round(float(np.median(got)), 2),
                            f"alarm_{key}_max_s": round(max(got), 2),
                            f"named_{key}_median_s": round(float(np.median(named)), 2),
                            f"named_{key}_max_s": round(max(named), 2),
                            f"within_1s_{key}": within, f"bumps_{key}": len(rows)})
            late = [r for r in st["rows"] if r[1] is None or r[1] > 1.0]
            for kind, delay, since, _, _ in late:
                print(f"  alarm over 1 s: tracker {kind} {since:.1f} s after a robot move and "
                      f"{a.hold_s - since:.1f} s before the next (settle 1 s): "
                      f"{'missed' if delay is None else f'{delay:.2f} s'}")
            print(f"  alarms without a bump: {st['false']}")
            fig["detection_false_alarms"] = st["false"]
        if a.minutes:
            print(f"false alarms: {a.minutes:g} min of session on the fast clock (tracker "
                  f"time), a robot correction every {a.hold_s:g} s")
            r = false_alarms(tmp, cal, a.minutes, a.hold_s, a.seed)
            s = r["mon"].summary()
            level = s["rule"]["level"]
            print(f"  {s['frames']} frames ({s['seconds'] / 60:.1f} min of tracker time, "
                  f"{r['wall_s']:.0f} s of wall time), {r['moves']} robot moves, "
                  f"{s['checked']} frames checked ({s['checked'] / s['frames']:.0%}), "
                  f"alarms: {s['alarms']}")
            expected = level * (r["moves"] + 1)
            print(f"  stated: ≤ {level:g} per still phase, {expected:.1g} expected in these "
                  f"{r['moves'] + 1} phases")
            for e in r["alarms"]:
                print(f"    {e.message}")
            m = f"fa_{a.minutes:g}min".replace(".", "_")
            fig.update({f"{m}_alarms": s["alarms"], f"{m}_moves": r["moves"],
                        f"{m}_checked_share": round(s["checked"] / s["frames"], 2),
                        f"{m}_wall_s": round(r["wall_s"])})
            cov = r["mon"].covariances()
            if cov is not None and a.sim_holds:
                bodies, S, Sf = cov
                frames = int(round(a.hold_s * 60))
                print(f"  the rule on {a.sim_holds} simulated unchanged holds of {a.hold_s:g} s "
                      f"(S of the last hold, {', '.join(bodies)}; the frame noise learnt on "
                      "the mock), false-alarm share per hold against the level:")
                for lv in (1e-2, 1e-3):
                    res = simulate_holds(Rule(window=15, level=lv), S, Sf, a.sim_holds,
                                         frames, np.random.default_rng(a.seed))
                    print(f"    level {lv:g}: {res['share']:.4f} ({res['alarms']} of "
                          f"{a.sim_holds})")
                    fig[f"sim_share_level_{lv:g}".replace("-", "m").replace(".", "_")] = \
                        round(res["share"], 4)
    record("monitor", fig)


if __name__ == "__main__":
    main()
