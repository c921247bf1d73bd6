"""What ``gpf-nav replay`` reports: the summary dict (counts, evaluation against truth, speed) and its print.

Truth is compared with the estimate of every filter update (the posterior at each measurement stamp),
linearly interpolated between truth samples at most :data:`TRUTH_GAP` s apart (:func:`truth_at`).
Position and velocity RMSE and the NEES come from :mod:`gpf_nav.experiments.metrics`.
"""
from __future__ import annotations

import numpy as np

TRUTH_GAP = 1.0
"""s: truth is interpolated only between samples at most this far apart."""


def truth_at(truth: dict[int, np.ndarray], stamps: np.ndarray, max_gap_ns: int) -> np.ndarray:
    """Truth ``(K, 6)`` at ``stamps`` ``(K,)`` [ns], linearly interpolated between samples at most
    ``max_gap_ns`` apart (NaN rows where there is no such pair, or no truth)."""
    out = np.full((len(stamps), 6), np.nan)
    if not truth or not len(stamps):
        return out
    t = np.array(sorted(truth), dtype=np.int64)
    x = np.array([truth[k] for k in t])
    i = np.searchsorted(t, stamps, side="left")
    exact = (i < len(t)) & (t[np.minimum(i, len(t) - 1)] == stamps)
    out[exact] = x[i[exact]]
    inner = ~exact & (i > 0) & (i < len(t))
    lo, hi = i[inner] - 1, i[inner]
    ok = (t[hi] - t[lo]) <= max_gap_ns
    s = ((stamps[inner] - t[lo]) / (t[hi] - t[lo]))[:, None]
    rows = np.flatnonzero(inner)[ok]
    out[rows] = ((1 - s) * x[lo] + s * x[hi])[ok]
    return out


def summarize(core, reader, name, present, read, undecodable, truth_wrong_frame, updates, truth, truth_read,
              writer, storage, wall, cpu, last_diag, log) -> tuple[dict, tuple | None]:
    """The replay's summary dict and, when truth covers some updates, ``(times (K,) s since the first
    compared update, errors (K, 6), filter standard deviations (K, 6))`` for the figure.

    ``updates`` are ``(stamp ns, mean (6,), covariance (6, 6))`` of each filter update, ``truth`` maps a
    stamp [ns] to the true state ``(6,)``; the rest is the replay's state (see :mod:`gpf_nav.bags.replay`).
    """
    from gpf_nav.experiments.metrics import error_norms, nees, rmse
    c = core.engine.counters
    span = (reader.end_ns - reader.start_ns) * 1e-9
    inputs = {}
    for topic, (stream, _) in present.items():
        row = {"read": read[topic], "undecodable": undecodable[topic]}
        if stream != "truth":
            row["accepted"] = c.accepted[stream]
            row["rejected"] = {r: n for (s, r), n in sorted(c.rejected_by_stream.items()) if s == stream and n}
        inputs[topic] = row
    summary = {
        "bag": str(reader.path), "filter": core.filter_name, "particles": core.params["n_particles"],
        "inputs": inputs,
        "rejected_by_reason": {r: n for r, n in c.rejected.items() if n},
        "undecodable": sum(undecodable.values()),
        "masked_components": c.masked,
        "updates": len(updates),
        "initialized_from": core.engine.init_source or None,
        "reinitializations": core.engine.reinit_count,
        "integrity_fault_updates": core.engine.integrity_fault_updates,
        "diagnostics_last": {"level": {0: "OK", 1: "WARN", 2: "ERROR"}.get(last_diag["level"], "none"),
                             "message": last_diag["message"]},
        "log_lines": dict(log.lines),
        "outputs": {"bag": str(writer.path), "storage": storage,
                    "messages": writer.counts},
        "bag_seconds": span, "wall_seconds": wall, "real_time_factor": span / wall if wall > 0 else None,
        "cpu_seconds": cpu, "real_time_factor_cpu": span / cpu if cpu > 0 else None,
        "truth": {"topic": name["truth/odometry"], "messages": truth_read, "decoded": len(truth),
                  "wrong_frame": truth_wrong_frame},
    }
    stamps = np.array([u[0] for u in updates], dtype=np.int64)
    ref = truth_at(truth, stamps, int(TRUTH_GAP * 1e9))
    have = np.all(np.isfinite(ref), axis=1)
    summary["truth"]["compared_updates"] = int(have.sum())
    evaluation = None
    if have.any():
        p, v = list(core.model.position_index), list(core.model.velocity_index)
        means = np.array([u[1] for u in updates])[have]
        covs = np.array([u[2] for u in updates])[have]
        err = means - ref[have]
        n = nees(err, covs)
        summary["position_rmse_m"] = rmse(error_norms(means[:, p], ref[have][:, p]))
        summary["velocity_rmse_mps"] = rmse(error_norms(means[:, v], ref[have][:, v]))
        summary["final_position_error_m"] = float(np.linalg.norm(err[-1, p]))
        t = stamps[have]
        late = t >= t[0] + (t[-1] - t[0]) // 2  # the updates of the second half of the compared span
        summary["position_rmse_second_half_m"] = rmse(error_norms(means[late][:, p], ref[have][late][:, p]))
        summary["velocity_rmse_second_half_mps"] = rmse(error_norms(means[late][:, v], ref[have][late][:, v]))
        summary["mean_nees"] = float(np.nanmean(n)) if np.any(np.isfinite(n)) else None
        summary["nees_dof"] = len(p) + len(v)
        order = p + v
        sig = np.sqrt(np.maximum(np.einsum("kii->ki", covs), 0.0))[:, order]
        evaluation = ((stamps[have] - stamps[have][0]) * 1e-9, err[:, order], sig)
    return summary, evaluation


def print_summary(summary: dict) -> None:
    def factor(value):
        return "n/a" if not value else f"{value:.0f}x"
    print(f"gpf-nav replay: {summary['filter']} N={summary['particles']} over {summary['bag']}: "
          f"{summary['bag_seconds']:.1f} s of data in {summary['wall_seconds']:.2f} s wall, "
          f"{factor(summary['real_time_factor'])} real time ({summary['cpu_seconds']:.2f} s of CPU: "
          f"{factor(summary['real_time_factor_cpu'])})")
    print(f"  {'input topic':28} {'read':>8} {'accepted':>9} {'rejected':>9} {'undecodable':>12}")
    for topic, row in summary["inputs"].items():
        rejected = sum(row.get("rejected", {}).values())
        print(f"  {topic:28} {row['read']:>8} {row.get('accepted', '-'):>9} "
              f"{rejected if 'accepted' in row else '-':>9} {row['undecodable']:>12}")
    reasons = summary["rejected_by_reason"]
    print("  rejected by reason          : " + (", ".join(f"{r} {n}" for r, n in reasons.items()) or "none"))
    print(f"  filter updates              : {summary['updates']} (initialised from "
          f"{summary['initialized_from'] or 'nothing'}; {summary['reinitializations']} re-initialisations; "
          f"{summary['masked_components']} masked components)")
    t = summary["truth"]
    if "position_rmse_m" in summary:
        nees_text = "n/a" if summary["mean_nees"] is None else f"{summary['mean_nees']:.2f}"
        print(f"  vs truth ({t['topic']}, {t['compared_updates']} updates): position RMSE "
              f"{summary['position_rmse_m']:.1f} m (final {summary['final_position_error_m']:.1f} m), velocity RMSE "
              f"{summary['velocity_rmse_mps']:.3f} m/s, mean NEES {nees_text} "
              f"({summary['nees_dof']} for a consistent filter); second half: position RMSE "
              f"{summary['position_rmse_second_half_m']:.1f} m, velocity RMSE "
              f"{summary['velocity_rmse_second_half_mps']:.3f} m/s")
    else:
        print(f"  vs truth                    : no truth to compare ({t['topic']}: {t['messages']} usable messages, "
              f"{t['wrong_frame']} in another frame)")
    d = summary["diagnostics_last"]
    print(f"  last /diagnostics           : {d['level']}: {d['message']}")
    out = summary["outputs"]
    print(f"  output bag ({out['storage']:7})        : {out['bag']}: "
          + ", ".join(f"{k} {n}" for k, n in out["messages"].items()))
    for key in ("summary_file", "figure"):
        if summary.get(key):
            print(f"  {key.replace('_', ' '):28}: {summary[key]}")
