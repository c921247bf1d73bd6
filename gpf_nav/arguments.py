"""Argument parsing shared by every command: a parser whose error is one line and exit status 2, and
the argparse types for positive and non-negative numbers."""
from __future__ import annotations

import argparse

USAGE_ERROR = 2


class CommandParser(argparse.ArgumentParser):
    """The sub-commands' argument parser: an error is one line, ``<prog>: error: <problem>``, on
    stderr, and exit status 2 (argparse's own convention, without the usage block)."""

    def error(self, message: str):
        self.exit(USAGE_ERROR, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive integer")
    return value


def non_negative_int(text: str) -> int:
    """argparse type: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r} is not a non-negative integer")
    return value


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not (0.0 < value < float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r} is not a positive number")
    return value
