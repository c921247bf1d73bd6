"""Clean exit of the console-script nodes on SIGINT or SIGTERM, whoever sends it.

``ros2 launch`` stopped with Ctrl-C delivers SIGINT twice to each node (the terminal's, to the whole
process group, then launch's own), and later SIGTERM if a node is slow. rclpy's default handler turns
a signal into ``KeyboardInterrupt`` wherever Python happens to be, for example inside
``destroy_node()``, which then prints a traceback and exits with -2. Instead,
:func:`init_without_signal_handlers` installs handlers that only *request* the stop and initialises
rclpy without its own; :func:`spin_until` notices the request within ``period`` s; :func:`close`
destroys the node and shuts rclpy down while the handlers are still in place (a repeated signal just
repeats the request), then ignores the signals until the process has exited; the console script
returns 0. :func:`run` is the whole life of a console-script node in that order.
"""
from __future__ import annotations

import signal
import time
from typing import Callable

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class StopRequest:
    """Set by SIGINT/SIGTERM once :meth:`install` has run. ``signum`` is the first signal received."""

    def __init__(self):
        self.signum: int | None = None

    def install(self) -> None:
        for sig in SIGNALS:
            signal.signal(sig, self._handle)

    def _handle(self, signum, frame) -> None:
        if self.signum is None:
            self.signum = signum

    def __bool__(self) -> bool:
        return self.signum is not None


def init_without_signal_handlers(args: list[str]) -> StopRequest:
    """Install the stop request handlers, then ``rclpy.init`` without rclpy's own."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    stop = StopRequest()
    stop.install()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    return stop


def start(program: str, args: list[str]) -> StopRequest | None:
    """:func:`init_without_signal_handlers` for a console script, after checking the params files of
    ``args``: a missing, unreadable or malformed params file (or any argument rcl cannot parse) gives one
    line on stderr, ``<program>: error: ...`` naming it, and None; the script then exits with status 2."""
    import sys

    from rclpy.impl.implementation_singleton import rclpy_implementation

    from gpf_nav.ros.parameters import params_file_error

    problem = params_file_error(args)
    if problem is None:
        try:
            return init_without_signal_handlers(args)
        except rclpy_implementation.RCLError as err:  # rcl's argument or params-file parser
            problem = "cannot start with these arguments: " + " ".join(str(err).split())
    print(f"{program}: error: {problem}", file=sys.stderr)
    return None


def spin_until(node, stop: StopRequest, done: Callable[[], bool] = lambda: False, period: float = 0.1) -> None:
    """Spin ``node`` until a stop is requested, ``done()`` is true or the context is shut down."""
    import rclpy
    from rclpy.executors import ExternalShutdownException

    try:
        while not stop and not done() and rclpy.ok():
            rclpy.spin_once(node, timeout_sec=period)
    except ExternalShutdownException:
        pass


def close(node) -> None:
    """Destroy ``node``, shut rclpy down (safe with the context already shut down), then ignore
    SIGINT/SIGTERM: the process is exiting, and Python's finalisation would otherwise restore the
    default action, which kills the process (exit -2) if a late signal arrives during it."""
    import rclpy

    try:
        if node is not None:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
        for sig in SIGNALS:
            signal.signal(sig, signal.SIG_IGN)


def run(program: str, logger: str, build: Callable[[], object], argv: list[str], done: Callable[[object], bool],
        linger: float = 0.0) -> int:
    """A console-script node's life: :func:`start` (2 on bad arguments), ``build()`` the node (2 after a
    FATAL line on ``logger`` when its parameters are invalid), spin until a stop request or ``done(node)``,
    then ``linger`` s more (so that reliable subscribers receive the last messages), :func:`close`; 0."""
    import rclpy
    import rclpy.exceptions
    import rclpy.logging

    from gpf_nav.schema import ParameterError

    stop = start(program, argv)
    if stop is None:
        return 2
    try:
        node = build()
    except (ParameterError, rclpy.exceptions.InvalidParameterTypeException,
            rclpy.exceptions.InvalidParameterValueException) as err:
        rclpy.logging.get_logger(logger).fatal(f"refusing to start: {err}")
        rclpy.try_shutdown()
        return 2
    try:
        spin_until(node, stop, done=lambda: done(node))
        if linger > 0.0:
            end = time.monotonic() + linger
            spin_until(node, stop, done=lambda: time.monotonic() > end)
    finally:
        close(node)
    return 0
