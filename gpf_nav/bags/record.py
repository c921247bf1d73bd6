"""``gpf-nav record OUT``: the simulator's scenario written as a rosbag2 bag, without running ROS.

The same parameters (``config/simulator.yaml``, ``-p name:=value``), events
(:func:`gpf_nav.sim.playback.build_events`) and messages (:func:`gpf_nav.ros.simulator_node.event_message`)
as ``ros2 run gpf_nav simulator`` at ``rate_factor`` 1, only as fast as the disk allows. With
``publish_clock: true`` (the default):

* ``/measurements/rae``, ``/imu``, ``/truth/odometry`` stamped ``start_time`` + trajectory time
  (``start_time`` negative, the default: the wall-clock time when the recording starts);
* ``/clock`` every ``1 / clock_rate`` s of simulated time, before the events of the same time;
* ``/set_state``, the scenario's prior handed over at the trajectory start (unless ``hand_over_prior``
  is false), right after the first ``/clock``;
* each message's recording time is its stamp (``/clock``: its time); each topic's offered QoS is the
  simulator's (reliable, keep last 1000, volatile; ``/set_state`` keep last 1, transient local), so
  ``ros2 bag play`` publishes it the same way.

Play it with ``ros2 bag play OUT`` and run the subscribers with ``use_sim_time:=true`` (the bag carries
``/clock``; do not add ``--clock``). With ``publish_clock: false``, as the simulator then does, there is
no ``/clock`` and the stamps follow the wall clock from the start of the recording (``start_time`` is
ignored): play it with ``ros2 bag play --clock`` if the subscribers use simulated time. Exit status 2, after
one line on stderr, on invalid parameters or an existing ``OUT``; exit status 1, after one line naming the
parameters to check, when the bag holds no measurement (all dropped, or a trajectory shorter than one
measurement period).
"""
from __future__ import annotations

import sys
import time

from gpf_nav.arguments import CommandParser, positive_float
from gpf_nav.bags.bag import STORAGES, BagError, BagWriter, absolute, qos_profile
from gpf_nav.estimator.params import ParameterError, parameters_from_files
from gpf_nav.sim.simulator_params import check_simulator_parameters, simulator_specs

CLOCK_TOPIC = "/clock"
NOTHING_WRITTEN = 1  # exit status of a recording without a measurement


def _parser() -> CommandParser:
    ap = CommandParser(prog="gpf-nav record", description=__doc__.split("\n\n")[0])
    ap.add_argument("out", metavar="OUT", help="bag directory to create")
    ap.add_argument("--duration", type=positive_float, help="simulated seconds (scenario.duration; default 2400)")
    ap.add_argument("--case", choices=("full", "partial"), help="measurement case (scenario.case; default full)")
    ap.add_argument("--seed", type=int, help="scenario seed (default 0)")
    ap.add_argument("--storage", choices=STORAGES, default="mcap", help="rosbag2 storage (default mcap)")
    ap.add_argument("--params-file", action="append", default=[], metavar="YAML",
                    help="simulator parameters (ROS 2 params file, e.g. config/simulator.yaml); repeatable")
    ap.add_argument("-p", "--param", action="append", default=[], metavar="NAME:=VALUE",
                    help="one simulator parameter, e.g. -p scenario.epsilon:=0.0; repeatable")
    return ap


def simulator_parameters(args) -> dict:
    """The simulator's parameters from the files, ``-p`` and the shortcut options (in that order)."""
    from gpf_nav.ros.simulator_node import NODE_NAME
    assignments = list(args.param)
    for option, name in (("duration", "scenario.duration"), ("case", "scenario.case"), ("seed", "seed")):
        value = getattr(args, option)
        if value is not None:
            assignments.append(f"{name}:={value}")
    return parameters_from_files(simulator_specs(), NODE_NAME, args.params_file, assignments)


def record(out: str, p: dict, storage: str = "mcap") -> dict:
    """Write the scenario of simulator parameters ``p`` to the bag ``out``; returns counts per topic."""
    from nav_msgs.msg import Odometry
    from rosgraph_msgs.msg import Clock

    from gpf_nav.ros import conversions as conv
    from gpf_nav.sim.playback import NS
    from gpf_nav.ros.simulator_node import (EVENT_TOPICS, HANDOVER_TOPIC, QOS_DEPTH,
                                            event_message, events_from_parameters, handover_message,
                                            scenario_from_parameters)
    errors = check_simulator_parameters(p)
    clock = p["publish_clock"]
    epoch = int(round(p["start_time"] * NS)) if clock and p["start_time"] >= 0.0 else time.time_ns()
    if not errors:
        try:
            _, scenario = scenario_from_parameters(p)
            events = events_from_parameters(scenario, p, epoch / NS)
        except (ValueError, OSError) as err:
            errors.append(f"scenario: {err}")
    if errors:
        raise ParameterError("invalid parameters: " + "; ".join(errors))
    span = max(e.t_ns for e in events)
    period = int(round(NS / p["clock_rate"]))
    qos = qos_profile(reliable=True, depth=QOS_DEPTH)
    kinds = {e.kind for e in events}
    topics = {absolute(topic): (msg_type, qos) for kind, (topic, msg_type) in EVENT_TOPICS.items()
              if kind in kinds or kind in ("measurement", "truth", "imu")}
    if clock:
        topics[CLOCK_TOPIC] = (Clock, qos)
    if p["hand_over_prior"]:
        topics[absolute(HANDOVER_TOPIC)] = (Odometry, qos_profile(reliable=True, depth=1, transient_local=True))
    with BagWriter(out, storage, topics) as bag:
        if clock:
            bag.write(CLOCK_TOPIC, Clock(clock=conv.ns_to_stamp(epoch)), epoch)
        if p["hand_over_prior"]:
            bag.write(absolute(HANDOVER_TOPIC), handover_message(scenario, epoch, p), epoch)
        tick = period
        for event in events + [None]:
            until = span if event is None else event.t_ns
            while clock and tick <= until:
                bag.write(CLOCK_TOPIC, Clock(clock=conv.ns_to_stamp(epoch + tick)), epoch + tick)
                tick += period
            if event is not None:
                topic, msg = event_message(event, epoch + event.t_ns, p)
                bag.write(absolute(topic), msg, epoch + event.t_ns)
    return bag.counts


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    start = time.perf_counter()
    try:
        p = simulator_parameters(args)
        counts = record(args.out, p, args.storage)
    except (ParameterError, BagError) as err:
        print(f"gpf-nav record: error: {err}", file=sys.stderr)
        return 2
    listing = ", ".join(f"{topic} {n}" for topic, n in counts.items())
    print(f"gpf-nav record: wrote {args.out} ({args.storage}) in {time.perf_counter() - start:.1f} s: {listing}")
    from gpf_nav.ros.simulator_node import EVENT_TOPICS
    topic = absolute(EVENT_TOPICS["measurement"][0])
    if not counts.get(topic):
        print(f"gpf-nav record: error: no measurement written ({topic} 0): every one was dropped or the "
              f"trajectory is shorter than one measurement period; see scenario.dropout_probability "
              f"(= {p['scenario.dropout_probability']}), scenario.duration (= {p['scenario.duration']}) and "
              f"scenario.dt (= {p['scenario.dt']})", file=sys.stderr)
        return NOTHING_WRITTEN
    return 0


if __name__ == "__main__":
    sys.exit(main())
