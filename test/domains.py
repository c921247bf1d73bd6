"""ROS domain ids for the tests' private graphs: one shuffled sequence of 110-229 for the whole pytest
process, so no two graphs of a session share a domain (a participant that an earlier test killed stays
announced for its lease, and a client may send its request to it). Another pytest process on the
machine draws its own order."""
import itertools
import os
import random
import time

_ORDER = random.Random(os.getpid() ^ time.time_ns()).sample(range(110, 230), 120)
_NEXT = itertools.cycle(_ORDER)


def fresh_domain() -> int:
    """A domain id no earlier graph of this pytest process has used (until 120 have been)."""
    return next(_NEXT)
