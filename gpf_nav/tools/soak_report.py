"""The soak's report: the checks, the accounting of every message, and the summary as a text table.

Pass/fail (exit code 0/1): the run completed, the estimator process was alive to the end and exited
cleanly on SIGINT, counters match the ledger's prediction exactly, the estimator counted all but at most
``--max-imu-loss`` of the simulator's IMU samples (they are not injected into: a node that keeps up loses
none; one that falls behind loses the overflow of its queue), no ``internal_error`` or ``filter_error``, no
non-finite number on any output, no ERROR/FATAL line or traceback in the estimator's log, and the
estimate follows the truth: the median position error over the second half of the compared estimates
is at most ``--max-error`` (a diverged filter ends thousands of kilometres off). With timing events, each
must have been injected and odometry must come back within ``--max-gap`` wall s over the quiet span
after it. RSS figures are reported, not judged. See docs/soak.md.
"""
from __future__ import annotations

import argparse
import math

import numpy as np

from gpf_nav.estimator.input_checks import REASONS
from gpf_nav.tools.soak_injector import QUIET_S, Injector
from gpf_nav.tools.soak_ledger import GARBAGE, STREAM_CATEGORIES
from gpf_nav.tools.soak_listener import Listener


def _second_half_growth(samples: list[tuple[float, float, int]]) -> int | None:
    """RSS change [KiB] from the sample nearest the middle of the simulated span to the last one."""
    if len(samples) < 3:
        return None
    middle = 0.5 * (samples[0][1] + samples[-1][1])
    mid = min(samples, key=lambda s: abs(s[1] - middle))
    return samples[-1][2] - mid[2]


def _slope_per_hour(samples: list[tuple[float, float, int]]) -> float | None:
    """Least-squares RSS growth [KiB per simulated hour] of ``(wall_s, sim_s, rss_kib)`` samples."""
    if len(samples) < 3:
        return None
    sim = np.array([s[1] for s in samples])
    rss = np.array([s[2] for s in samples], dtype=float)
    if np.ptp(sim) <= 0:
        return None
    return float(np.polyfit(sim, rss, 1)[0] * 3600.0)


def summarise(args: argparse.Namespace, command: str, sim, injector: Injector, listener: Listener, alive: bool,
              exit_code: int, log_text: str, rss_start: dict, rss_end: dict,
              rss_samples: list[tuple[float, float, int]], own_start: dict, own_end: dict, sim_wall: float,
              wall: float) -> dict:
    """The summary of a run: the checks, the accounting against the ledger, outputs, errors and memory.

    ``sim`` has ``finished`` and ``published`` (counts by kind, over every simulator of the run).
    """
    ledger = injector.ledger
    v = listener.last_values
    counted = {r: int(v.get(f"rejected {r}", -1)) for r in REASONS}
    accepted = int(v.get("accepted rae", -1))
    masked = int(v.get("masked components", -1))
    reasons = []
    for r in REASONS:
        reasons.append({"reason": r, "expected": ledger.expected_rejected[r], "counted": counted[r],
                        "match": ledger.expected_rejected[r] == counted[r]})
    accounted = (all(row["match"] for row in reasons) and accepted == ledger.expected_accepted
                 and masked == ledger.expected_masked)
    seen = accepted + int(v.get("measurements rejected", 0)) if v else -1
    errors = listener.errors()
    late = errors[errors.size // 2:]
    late_median = float(np.median(late)) if late.size else math.nan
    imu_published, imu_accepted = sim.published["imu"], int(v.get("accepted imu", -1))
    imu_loss = 1.0 - imu_accepted / imu_published if imu_published else 0.0
    non_finite = sum(listener.non_finite.values())
    events = [{"event": e["event"], "stamp_s": round(e["stamp_ns"] * 1e-9, 3), **listener.gap_after(e["wall"], QUIET_S / args.rate_factor)}
              for e in injector.events]
    wanted = [name for name, at in (("restart", args.restart_at), ("late burst", args.late_burst_at),
                                    ("fault", args.fault_at)) if at is not None]
    log_problems = [line for line in log_text.splitlines() if "Traceback" in line or "internal_error" in line
                    or "[ERROR]" in line or "[FATAL]" in line]
    checks = {
        "run completed": bool(sim.finished),
        "estimator alive to the end": alive,
        "estimator exited cleanly on SIGINT": exit_code == 0,
        "every message accounted for": accounted,
        f"IMU samples counted (at most {args.max_imu_loss:.0%} lost)": imu_loss <= args.max_imu_loss,
        "no internal_error or filter_error": counted["internal_error"] == 0 and counted["filter_error"] == 0,
        "no non-finite output": non_finite == 0 and listener.counts["odometry/filtered"] > 0,
        "no ERROR, FATAL or traceback in the estimator log": not log_problems,
        f"estimate follows truth (second-half median error <= {args.max_error:g} m)": late_median <= args.max_error,
    }
    if wanted:
        checks[f"events injected ({', '.join(wanted)}), odometry back within {args.max_gap:g} wall s of each"] = (
            sorted(e["event"] for e in events) == sorted(wanted)
            and all(e["max_gap_wall_s"] is not None and e["max_gap_wall_s"] <= args.max_gap for e in events))
    growth = None
    if rss_start.get("VmRSS") and rss_end.get("VmRSS"):
        growth = rss_end["VmRSS"] - rss_start["VmRSS"]
    return {
        "completed": bool(sim.finished),
        "passed": all(checks.values()),
        "checks": checks,
        "command": command,
        "filter": args.filter,
        "particles": args.particles,
        "seed": args.seed,
        "epsilon": args.epsilon,
        "rate_factor": args.rate_factor,
        "simulated_minutes": args.sim_minutes,
        "warmup_s": args.warmup,
        "wall_seconds": round(wall, 1),
        "wall_seconds_simulation": round(sim_wall, 1),
        "simulator_measurements": sim.published["measurement"],
        "imu_published": imu_published,
        "imu_accepted": imu_accepted,
        "stream": dict(ledger.stream),
        "garbage": dict(ledger.garbage),
        "garbage_single": ledger.singles,
        "bursts": ledger.bursts,
        "burst_messages": ledger.burst_messages,
        "late_burst_messages": ledger.late_burst,
        "events": events,
        "delayed_verdicts": dict(ledger.delayed_outcomes),
        "duplicate_verdicts": dict(ledger.duplicate_outcomes),
        "sent_to_estimator": ledger.sent,
        "seen_by_estimator": seen,
        "expected_accepted": ledger.expected_accepted,
        "accepted": accepted,
        "expected_masked": ledger.expected_masked,
        "masked": masked,
        "reasons": reasons,
        "accounted": accounted,
        "rss_kib": {
            "estimator_start": rss_start.get("VmRSS"), "estimator_end": rss_end.get("VmRSS"),
            "estimator_growth": growth, "estimator_peak": rss_end.get("VmHWM"),
            "estimator_max_sampled": max((s[2] for s in rss_samples), default=None),
            "estimator_slope_per_sim_hour": _round(_slope_per_hour(rss_samples)),
            "estimator_second_half_growth": _second_half_growth(rss_samples),
            "soak_process_start": own_start.get("VmRSS"), "soak_process_end": own_end.get("VmRSS"),
            "samples": len(rss_samples),
        },
        "rss_series": [(round(w, 1), round(s, 1), r) for w, s, r in rss_samples],
        "outputs_checked": dict(listener.counts),
        "non_finite_outputs": dict(listener.non_finite),
        "first_non_finite": listener.first_non_finite,
        "diagnostics_levels": dict(listener.levels),
        "diagnostics_causes": {k: n for k, n in listener.messages.items() if k != "tracking"},
        "final_diagnostics": {k: v.get(k) for k in (
            "initialized from", "reinitializations", "ESS", "integrity level", "integrity samples",
            "integrity components", "integrity fault updates", "integrity warn updates", "integrity skipped updates",
            "integrity resets", "integrity fault reinitializations", "node clock jumps back", "accepted imu",
            "messages rejected")},
        "position_error_m": {"median": _round(float(np.median(errors))) if errors.size else None,
                             "p95": _round(float(np.percentile(errors, 95))) if errors.size else None,
                             "final": _round(float(errors[-1])) if errors.size else None,
                             "second_half_median": _round(late_median),
                             "compared": int(errors.size)},
        "estimator_log_problems": log_problems[:10],
    }


def _round(x: float | None, digits: int = 1) -> float | None:
    return None if x is None or not math.isfinite(x) else round(x, digits)


def format_summary(s: dict) -> str:
    """The summary as a text table."""
    L = []
    L.append(f"gpf_nav soak: {s['filter']} N={s['particles']}, {s['simulated_minutes']:g} simulated min at "
             f"{s['rate_factor']:g}x in {s['wall_seconds']:.0f} s wall (seed {s['seed']}, epsilon {s['epsilon']:g})"
             + ("" if s["completed"] else "  ** DID NOT COMPLETE **"))
    L.append(f"  command: {s['command']}")
    r = s["rss_kib"]

    def mib(x):
        return "n/a" if x is None else f"{x / 1024:.1f} MiB"
    L.append(f"  estimator RSS: start {mib(r['estimator_start'])} (after {s['warmup_s']:g} s warm-up), "
             f"end {mib(r['estimator_end'])}, peak {mib(r['estimator_peak'])}")
    L.append(f"    growth {r['estimator_growth']} KiB ({r['estimator_second_half_growth']} KiB in the second half), "
             f"least-squares trend {r['estimator_slope_per_sim_hour']} KiB per simulated hour, {r['samples']} samples")
    L.append(f"  soak process RSS: start {mib(r['soak_process_start'])}, end {mib(r['soak_process_end'])}")
    L.append("")
    L.append(f"  {'measurements from the simulator':34} {s['simulator_measurements']:>7}")
    for c in STREAM_CATEGORIES:
        note = {"passed": "sent unchanged", "dropped": "never sent",
                "delayed": f"sent after 1-3 newer ones: {_verdicts(s['delayed_verdicts'])}",
                "duplicated": f"sent twice; 2nd copy: {_verdicts(s['duplicate_verdicts'])}",
                "masked": "range NaN: accepted, masked"}[c]
        L.append(f"    {c:32} {s['stream'][c]:>7}   {note}")
    L.append(f"  {'garbage messages':34} {sum(s['garbage'].values()):>7}   "
             f"({s['garbage_single']} single, {s['burst_messages']} in {s['bursts']} bursts)")
    reason_of = dict(GARBAGE)
    for kind, n in s["garbage"].items():
        L.append(f"    {kind:32} {n:>7}   -> {reason_of[kind]}")
    if s["late_burst_messages"]:
        L.append(f"  {'late burst (6 s late copies)':34} {s['late_burst_messages']:>7}")
    for e in s["events"]:
        L.append(f"  event {e['event']:12} at {e['stamp_s']:.1f} s: first odometry after {e['first_odometry_wall_s']} "
                 f"wall s, longest gap {e['max_gap_wall_s']} wall s ({e['max_gap_stamp_s']} s of stamps)")
    L.append(f"  {'sent to the estimator':34} {s['sent_to_estimator']:>7}   counted by it: {s['seen_by_estimator']}")
    L.append(f"  {'imu (simulator -> estimator)':34} {s['imu_published']:>7}   accepted: {s['imu_accepted']}")
    L.append("")
    L.append(f"  {'verdict':32} {'expected':>9} {'counted':>9}")
    L.append(f"  {'accepted rae':32} {s['expected_accepted']:>9} {s['accepted']:>9}"
             + ("" if s["expected_accepted"] == s["accepted"] else "   MISMATCH"))
    L.append(f"  {'masked components':32} {s['expected_masked']:>9} {s['masked']:>9}"
             + ("" if s["expected_masked"] == s["masked"] else "   MISMATCH"))
    for row in s["reasons"]:
        if row["expected"] or row["counted"]:
            L.append(f"  {'rejected ' + row['reason']:32} {row['expected']:>9} {row['counted']:>9}"
                     + ("" if row["match"] else "   MISMATCH"))
    L.append(f"  (every other reason: expected 0, counted "
             f"{sum(r['counted'] for r in s['reasons'] if not r['expected'])})")
    L.append("")
    L.append("  outputs checked: " + ", ".join(f"{k} {n}" for k, n in sorted(s["outputs_checked"].items()))
             + f"; non-finite: {sum(s['non_finite_outputs'].values())}")
    e = s["position_error_m"]
    L.append(f"  position error vs truth: median {e['median']} m, p95 {e['p95']} m, final {e['final']} m, "
             f"second-half median {e['second_half_median']} m ({e['compared']} estimates)")
    L.append("  diagnostics levels: " + ", ".join(f"{k} {n}" for k, n in s["diagnostics_levels"].items())
             + ("; causes: " + ", ".join(f"{k} {n}" for k, n in s["diagnostics_causes"].items())
                if s["diagnostics_causes"] else ""))
    L.append("  final diagnostics: " + ", ".join(f"{k} {v}" for k, v in s["final_diagnostics"].items()))
    for line in s["estimator_log_problems"]:
        L.append(f"  estimator log: {line[:200]}")
    if s.get("estimator_log"):
        L.append(f"  estimator log file: {s['estimator_log']}")
    L.append("")
    for name, ok in s["checks"].items():
        L.append(f"  [{'PASS' if ok else 'FAIL'}] {name}")
    L.append(f"  soak {'PASSED' if s['passed'] else 'FAILED'}")
    return "\n".join(L)


def _verdicts(d: dict) -> str:
    return ", ".join(f"{k} {n}" for k, n in sorted(d.items())) or "none"

