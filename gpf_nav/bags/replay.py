"""``gpf-nav replay BAG --out DIR``: the estimator run offline over a rosbag2 bag, as fast as the CPU allows.

The estimator node's own message handling (:class:`gpf_nav.ros.message_layer.MessageLayer`: same
parameters, checks, counters and outputs) is fed the bag's messages in recording order, with no ROS
graph and no waiting:

* inputs: the node's topics (:data:`gpf_nav.ros.message_layer.INPUT_TOPICS`: ``measurements/rae``,
  ``measurements/range``, ``measurements/position``, ``measurements/velocity``, ``measurements/altitude``,
  ``imu``, ``set_pose``, ``set_state``) (the prior ``gpf-nav record`` writes at the start, as the simulator hands it over), plus
  ``truth/odometry`` for the evaluation; each remappable (``--remap measurements/rae:=/tracking/rae``);
* time: header stamps drive the filter, as in the node. The node clock (the ``future_stamp`` check,
  ``set_pose`` with a zero stamp, the ``publish_rate`` timer, diagnostics ages) is each message's
  recording time, or with ``-p use_sim_time:=true`` the bag's ``/clock``, as for a node on simulated
  time. The steady clock (rate limit, ERROR and alarm holds, the ``diagnostics_period`` timer) is the
  recording time, so a bag replays as it was received;
* parameters: ``--params-file`` (e.g. ``config/estimator.yaml``) and ``-p name:=value`` as for the node;
* outputs: ``DIR/estimates``, a rosbag2 bag of what the node publishes (``/odometry/filtered``,
  ``/gpf/ess``, ``/gpf/costate``, ``/gpf/unmodelled_acceleration``, ``/diagnostics``;
  ``/gpf/particles`` with ``--particles``), each
  recorded at the recording time of the message or timer tick that produced it; ``DIR/summary.json``, printed too; ``DIR/errors.png``
  (per-axis error and 3-sigma bounds) when the bag has truth.

Truth is compared with the estimate of every filter update (the posterior at each measurement stamp),
interpolated between truth samples at most 1 s apart (:mod:`gpf_nav.bags.replay_report`); truth
messages in another frame than ``world_frame`` are not used. Exit status 2, after one line on stderr, on invalid
parameters, an unreadable or truncated bag, a topic of the wrong type, or no measurement topic; exit status 1,
after the summary and one line on stderr with the counts by refusal reason and the parameter to set, when the
replay accepted no measurement (e.g. ``measurement_frame`` differs from the bag's frame).
"""
from __future__ import annotations

import json
import math
import shutil
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock

from gpf_nav.arguments import CommandParser
from gpf_nav.bags.bag import (STORAGES, BagError, BagReader, BagWriter, absolute, deserialize,
                             header_stamp_ns, qos_profile, type_name)
from gpf_nav.ros.conversions import odometry_state, stamp_to_ns
from gpf_nav.ros.message_layer import INPUT_TOPICS, OUTPUT_TOPICS, MessageLayer
from gpf_nav.estimator.params import ESTIMATOR, ParameterError, Spec, parameters_from_files
from gpf_nav.bags.replay_report import print_summary, summarize

TRUTH_TOPIC = "truth/odometry"
CLOCK_TOPIC = "/clock"
OUTPUT_DEPTH = 10  # the node's reliable publishers
MEASUREMENT_STREAMS = ("rae", "range")
NOTHING_ACCEPTED = 1  # exit status of a replay that ran but accepted no measurement


REPLAY_PARAMETERS = ESTIMATOR + [Spec("use_sim_time", False, "Node clock: the bag's /clock (true) or each "
                                                              "message's recording time (false).")]
"""The estimator's parameters plus rclpy's ``use_sim_time``, which the replay honours."""


class ReplayError(Exception):
    """A replay that cannot run (one-line message): bad remapping, wrong topic types, nothing to estimate."""


def _parser() -> CommandParser:
    ap = CommandParser(prog="gpf-nav replay", description=__doc__.split("\n\n")[0])
    ap.add_argument("bag", metavar="BAG", help="rosbag2 bag directory (MCAP or sqlite3)")
    ap.add_argument("--out", required=True, metavar="DIR", help="output directory (created)")
    ap.add_argument("--remap", action="append", default=[], metavar="FROM:=TO",
                    help="topic remapping, node name := bag name, e.g. measurements/rae:=/tracking/rae")
    ap.add_argument("--params-file", action="append", default=[], metavar="YAML",
                    help="estimator parameters (ROS 2 params file, e.g. config/estimator.yaml); repeatable")
    ap.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                    help="one estimator parameter, e.g. -p n_particles:=1000; repeatable")
    ap.add_argument("--storage", choices=STORAGES, default="mcap", help="output bag storage (default mcap)")
    ap.add_argument("--particles", action="store_true", help="also write gpf/particles")
    ap.add_argument("--no-figure", action="store_true", help="do not draw errors.png")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument("--json", action="store_true", help="print the summary as JSON")
    return ap


def parse_remaps(remaps) -> dict[str, str]:
    """``["from:=to", ...]`` -> ``{absolute from: absolute to}``."""
    out = {}
    for text in remaps:
        src, sep, dst = text.partition(":=")
        if not sep or not src or not dst:
            raise ReplayError(f"remapping {text!r} must read from:=to")
        out[absolute(src)] = absolute(dst)
    return out


class _Log:
    """Log lines of the estimator core on stderr, above the progress bar; also counted per level."""

    def __init__(self, write):
        self._write = write
        self.lines = Counter()

    def _line(self, level: str, text: str) -> None:
        self.lines[level] += 1
        self._write(f"[{level}] {text}")

    def info(self, text: str) -> None:
        self._line("INFO", text)

    def warning(self, text: str) -> None:
        self._line("WARN", text)

    def error(self, text: str) -> None:
        self._line("ERROR", text)


def _progress(total: int, disable: bool):
    """A tqdm bar on stderr (None without tqdm or when disabled) and a line writer that respects it."""
    def plain(text):
        print(text, file=sys.stderr)
    if disable:
        return None, plain
    try:
        from tqdm import tqdm
    except ImportError:
        return None, plain
    bar = tqdm(total=total, unit="msg", unit_scale=True, mininterval=0.5, file=sys.stderr,
               desc="replay", dynamic_ncols=True, disable=None)  # None: no bar when stderr is not a terminal
    return bar, lambda text: tqdm.write(text, file=sys.stderr)


def replay(bag_path: str, out_dir: str, params: dict, remaps: dict | None = None, storage: str = "mcap",
           particles: bool = False, progress: bool = True) -> tuple[dict, tuple | None]:
    """Run the estimator over ``bag_path``; write ``out_dir/estimates``. Returns the summary dict and, when
    there was truth, ``(times (K,) s, errors (K, 6), sigmas (K, 6))`` of the compared updates.

    Raises :class:`BagError`, :class:`ReplayError` or :class:`ParameterError` (nothing is left in
    ``out_dir/estimates`` then).
    """
    remaps = remaps or {}
    name = {topic: remaps.get(absolute(topic), absolute(topic))
            for topic in [*INPUT_TOPICS, TRUTH_TOPIC, CLOCK_TOPIC, *OUTPUT_TOPICS]}
    inputs = {name[t]: (stream, msg_type) for t, (stream, msg_type) in INPUT_TOPICS.items()}
    inputs[name[TRUTH_TOPIC]] = ("truth", Odometry)
    if params.get("use_sim_time"):
        inputs[name[CLOCK_TOPIC]] = ("clock", Clock)
    out_dir = Path(out_dir)
    out_bag = out_dir / "estimates"
    with BagReader(bag_path) as reader:
        present = {t: spec for t, spec in inputs.items() if t in reader.topics}
        for topic, (_, msg_type) in present.items():
            expected = type_name(msg_type)
            if reader.topics[topic] != expected:
                raise ReplayError(f"topic {topic} in {bag_path} has type {reader.topics[topic]}; the estimator "
                                  f"expects {expected} (remap another topic with --remap)")
        if not any(present.get(name[t], ("",))[0] in ("rae", "range")
                   for t in ("measurements/rae", "measurements/range")):
            raise ReplayError(f"no measurements in {bag_path}: neither {name['measurements/rae']} nor "
                              f"{name['measurements/range']} is in it (topics: {', '.join(sorted(reader.topics))}); "
                              "use --remap measurements/rae:=/your/topic")
        out_dir.mkdir(parents=True, exist_ok=True)
        if out_bag.exists():
            raise BagError(f"{out_bag} exists already; choose another --out")
        try:
            return _run(reader, out_bag, params, name, present, storage, particles, progress)
        except BaseException:
            shutil.rmtree(out_bag, ignore_errors=True)
            raise


def _run(reader, out_bag, params, name, present, storage, particles, progress) -> tuple[dict, tuple | None]:
    wall_start, cpu_start = time.perf_counter(), time.process_time()
    total = sum(reader.counts[t] for t in present)
    bar, write_line = _progress(total, disable=not progress)
    log = _Log(write_line)
    qos = qos_profile(reliable=True, depth=OUTPUT_DEPTH)
    wanted_outputs = {t: m for t, m in OUTPUT_TOPICS.items() if particles or t != "gpf/particles"}
    sim_time = bool(params.get("use_sim_time"))
    # rec: recording time (the steady clock and the time outputs are recorded at); node: the node clock
    clock = {"rec": reader.start_ns, "node": 0 if sim_time else reader.start_ns, "update": False}
    updates: list[tuple[int, np.ndarray, np.ndarray]] = []
    truth_raw: dict[int, bytes] = {}
    read, undecodable, frames = Counter(), Counter(), Counter()
    last_diag = {"level": None, "message": "none published"}

    with BagWriter(out_bag, storage, {name[t]: (m, qos) for t, m in wanted_outputs.items()}) as writer:
        def publish(topic: str, msg) -> None:
            if topic not in wanted_outputs:
                return
            writer.write(name[topic], msg, clock["rec"])
            if topic == "odometry/filtered" and clock["update"]:
                updates.append((stamp_to_ns(msg.header.stamp), core.engine.mean.copy(), core.engine.cov.copy()))

        core = MessageLayer(params, publish, log, monotonic=lambda: clock["rec"] * 1e-9,
                             wants_particles=lambda: particles)
        log.info(core.describe() + (" (node clock: /clock of the bag)" if sim_time else
                                    " (node clock: recording time)"))

        def diagnostics(t_ns: int) -> None:
            level, message = core.diagnostics_tick(clock["node"], (t_ns - reader.start_ns) * 1e-9, "/gpf_estimator")
            last_diag.update(level=level, message=message)

        publish_period = int(round(1e9 / params["publish_rate"])) if params["publish_rate"] > 0 else 0
        timers = [_Timer(int(round(1e9 * params["diagnostics_period"])), diagnostics, reader.start_ns)]
        publish_timer = _Timer(publish_period, core.publish_tick, None if sim_time else reader.start_ns)
        if publish_period and not sim_time:
            timers.append(publish_timer)

        def run_timers(until_ns: int) -> None:
            """Fire the recording-time timers due strictly before ``until_ns``, in time order."""
            while True:
                timer = min(timers, key=lambda x: x.due)
                if timer.due >= until_ns:
                    return
                clock["rec"] = timer.due
                if not sim_time:
                    clock["node"] = timer.due
                timer.fire(timer.due)

        for topic, t_ns, raw in reader.messages(present):
            run_timers(t_ns)
            clock["rec"] = t_ns
            if not sim_time:
                clock["node"] = t_ns
            read[topic] += 1
            stream, msg_type = present[topic]
            if stream == "truth":  # decoded after the loop, only around the updates (truth is dense)
                try:
                    truth_raw[header_stamp_ns(raw)] = raw
                except ValueError:
                    undecodable[topic] += 1
            else:
                try:
                    msg = deserialize(raw, msg_type)
                except Exception:  # noqa: BLE001 - a corrupt record is dropped and counted
                    undecodable[topic] += 1
                    if undecodable[topic] == 1:
                        log.warning(f"dropped a message on {topic} that does not deserialise as "
                                    f"{msg_type.__name__}")
                    msg = None
                if msg is None:
                    pass
                elif stream == "clock":
                    clock["node"] = stamp_to_ns(msg.clock)
                    if publish_period and clock["node"]:
                        publish_timer.step(clock["node"])
                else:
                    clock["update"] = stream in MEASUREMENT_STREAMS
                    if clock["update"]:
                        frames[msg.header.frame_id] += 1
                    core.handle(stream, msg, clock["node"])
                    clock["update"] = False
            if bar is not None:
                bar.update(1)
        run_timers(reader.end_ns + 1)
        clock["rec"] = max(reader.end_ns, clock["rec"])
        diagnostics(clock["rec"])
    if bar is not None:
        bar.close()
    truth, truth_wrong_frame = _decode_truth(truth_raw, [u[0] for u in updates], params["world_frame"],
                                             undecodable, name[TRUTH_TOPIC])
    wall, cpu = time.perf_counter() - wall_start, time.process_time() - cpu_start
    summary, evaluation = summarize(core, reader, name, present, read, undecodable, truth_wrong_frame, updates,
                                    truth, len(truth_raw), writer, storage, wall, cpu, last_diag, log)
    c = core.engine.counters
    rejected = Counter()
    for (stream, reason), n in c.rejected_by_stream.items():
        if stream in MEASUREMENT_STREAMS and n:
            rejected[reason] += n
    summary["measurements"] = {
        "read": sum(frames.values()), "accepted": sum(c.accepted[s] for s in MEASUREMENT_STREAMS),
        "rejected": dict(rejected), "frames": dict(frames), "measurement_frame": params["measurement_frame"]}
    return summary, evaluation


PARAMETER_FOR = {
    "wrong_frame": "measurement_frame",
    "future_stamp": "max_future, or use_sim_time:=true for a bag with /clock",
    "rate_limit": "max_measurement_rate (0: unlimited)",
    "range_out_of_limits": "nothing: the Range messages' own min_range/max_range refuse them",
}
"""Refusal reason -> the estimator parameter that decides it (the hint of :func:`nothing_accepted`)."""


def nothing_accepted(summary: dict) -> str:
    """'' when the replay accepted a measurement; otherwise why not: counts by reason and the parameter
    to set (naming the frames the bag's measurements are in when the frame was the problem)."""
    m = summary["measurements"]
    if m["accepted"]:
        return ""
    if not m["read"]:
        return "no measurement accepted: the measurement topics hold no decodable message"
    reasons = ", ".join(f"{r} {n}" for r, n in sorted(m["rejected"].items(), key=lambda rn: -rn[1]))
    text = f"no measurement accepted: {m['read']} read, refused by reason: {reasons or 'none'}"
    for reason in sorted(m["rejected"], key=lambda r: -m["rejected"][r]):
        if reason == "wrong_frame":
            seen = ", ".join(f"'{f}' ({n})" for f, n in sorted(m["frames"].items(), key=lambda fn: -fn[1]))
            best = max(m["frames"], key=m["frames"].get)
            text += (f". wrong_frame: the measurements' header.frame_id is {seen}, measurement_frame is "
                     f"'{m['measurement_frame']}': set -p measurement_frame:={best} (or '' for any frame)")
        elif reason in PARAMETER_FOR:
            text += f". {reason}: see the parameter {PARAMETER_FOR[reason]}"
    return text


def _decode_truth(raw: dict[int, bytes], stamps, world_frame: str, undecodable: Counter,
                  topic: str) -> tuple[dict[int, np.ndarray], int]:
    """States ``(6,)`` by stamp of the truth messages ``raw`` (serialised, by stamp) that bracket
    ``stamps``; also how many of those are in another frame than ``world_frame`` (not used)."""
    t = np.array(sorted(raw), dtype=np.int64)
    i = np.searchsorted(t, np.asarray(stamps, dtype=np.int64))
    wanted = np.unique(np.concatenate([i - 1, i]).clip(0, len(t) - 1)) if len(t) else []
    truth, wrong_frame = {}, 0
    for k in t[wanted].tolist():
        try:
            msg = deserialize(raw[k], Odometry)
        except Exception:  # noqa: BLE001
            undecodable[topic] += 1
            continue
        if msg.header.frame_id != world_frame:
            wrong_frame += 1
        else:
            truth[stamp_to_ns(msg.header.stamp)] = odometry_state(msg)
    return truth, wrong_frame


class _Timer:
    """A node timer of period ``period_ns`` replayed offline, first due one period after ``start_ns``.

    On a continuous clock (recording time) the caller fires every due tick at its own time (:meth:`fire`);
    on a clock that moves in steps (``/clock`` messages) :meth:`step` fires at most once per step and skips
    missed periods, as an rcl timer on simulated time does."""

    def __init__(self, period_ns: int, callback, start_ns: int | None):
        self.period, self.callback = period_ns, callback
        self.due = math.inf if start_ns is None or not period_ns else start_ns + period_ns

    def fire(self, now_ns: int) -> None:
        self.callback(now_ns)
        self.due += self.period

    def step(self, now_ns: int) -> None:
        if self.due == math.inf:
            self.due = now_ns + self.period
        elif now_ns >= self.due:
            self.callback(now_ns)
            self.due += self.period * ((now_ns - self.due) // self.period + 1)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    try:
        params = parameters_from_files(REPLAY_PARAMETERS, "gpf_estimator", args.params_file, args.param)
        summary, evaluation = replay(args.bag, args.out, params, parse_remaps(args.remap), args.storage,
                                     args.particles, progress=not args.no_progress)
    except (ParameterError, BagError, ReplayError) as err:
        print(f"gpf-nav replay: error: {err}", file=sys.stderr)
        return 2
    out = Path(args.out)
    if evaluation is not None and not args.no_figure:
        try:
            from gpf_nav.experiments.plots import estimate_errors
        except ImportError:
            summary["figure"] = None
        else:
            title = (f"{summary['filter']} N={summary['particles']} replayed over {Path(args.bag).name}: "
                     f"error against truth with the filter's 3σ bounds ({len(evaluation[0])} updates)")
            summary["figure"] = str(estimate_errors(*evaluation, title, out / "errors.png"))
    summary["summary_file"] = str(out / "summary.json")
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n")
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print_summary(summary)
    problem = nothing_accepted(summary)
    if problem:
        print(f"gpf-nav replay: error: {problem}", file=sys.stderr)
        return NOTHING_ACCEPTED
    return 0


if __name__ == "__main__":
    sys.exit(main())
