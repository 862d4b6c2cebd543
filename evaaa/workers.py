"""How a simulator spreads one decision over threads: the one place its threading lives.

MuJoCo's physics step and drawing calls free the GIL, so threads overlap where those calls dominate.  A batch is
split into shares whose physics run at once (the first on the calling thread, the others on helpers); a single
world's frame is drawn on the calling thread while a helper does the rest of the decision.  The results do not
depend on the number of threads: every world's work stays on one thread and reads only that world's state.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor


class Workers:
    """The threads one simulator of ``n`` worlds works on (``threads`` at once, the calling one included)."""

    def __init__(self, threads: int, n: int):
        self.threads = threads
        self.n = n
        #: the batch's shares (at most one per world)
        self.shares = min(threads, n)
        #: a single world's frame is drawn while a helper concludes its decision
        self.beside_frame = threads > n
        self._pool: ThreadPoolExecutor | None = None  # made when first needed

    @property
    def started(self) -> bool:
        """Whether a helper thread has been made."""
        return self._pool is not None

    def _helpers(self) -> ThreadPoolExecutor:
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads - 1, "evaaa-helper")
        return self._pool

    def each_share(self, work, *args) -> None:
        """``work(worlds, *args)`` for every share of the batch (``worlds`` a range), all at once."""
        shares, n = self.shares, self.n
        if shares <= 1:
            work(range(n), *args)
            return
        bounds = [n * i // shares for i in range(shares + 1)]
        others = [self._helpers().submit(work, range(a, b), *args) for a, b in zip(bounds[1:-1], bounds[2:])]
        work(range(bounds[1]), *args)
        for share in others:
            share.result()

    def while_drawing(self, draw, work):
        """``draw(before_draw)`` on this thread and ``work()`` on a helper, started by ``before_draw`` once the
        scene is ready (from then on the drawing thread holds the GIL only briefly); returns both results."""
        jobs = []

        def start():
            jobs.append(self._helpers().submit(work))

        try:
            drawn = draw(start)
        finally:
            if jobs:  # wait for the helper even when drawing failed: it must not outlive the decision
                done = jobs[0].result()
        if not jobs:  # the drawing never got to its scene: do the work here
            done = work()
        return drawn, done

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None
