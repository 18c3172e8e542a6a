"""A script's checks: made one at a time, printed, counted, summed up."""


class Checks:
    """The checks of one script (or one session of it).

    `checks(ok, what)` records one: printed as `  ok   what` or
    `  FAIL what` (with `quiet`, failures only), and returns `ok`.
    `summary()` is the line ./test.sh counts: `NAME check: N passed, M
    failed`; `exit_code()` is 1 when a check failed or none was made.
    """

    def __init__(self, name, quiet=False, flush=False):
        self.name = name
        self.quiet = quiet
        self.flush = flush
        self.results = []

    def __call__(self, ok, what):
        ok = bool(ok)
        self.results.append((ok, what))
        if not (ok and self.quiet):
            print(("  ok   " if ok else "  FAIL ") + what, flush=self.flush)
        return ok

    @property
    def passed(self):
        """How many checks held."""
        return sum(ok for ok, _ in self.results)

    @property
    def failed(self):
        """How many checks failed."""
        return len(self.results) - self.passed

    def failures(self):
        """What each failed check said."""
        return [what for ok, what in self.results if not ok]

    def summary(self, say_failures=False):
        """`NAME check: N passed, M failed`; with `say_failures`, what
        failed after it, in parentheses."""
        failures = self.failures()
        tail = f" ({'; '.join(failures)})" if say_failures and failures else ""
        return f"{self.name} check: {self.passed} passed, {self.failed} failed{tail}"

    def exit_code(self):
        """0 when every check held and there was at least one; else 1."""
        return 1 if self.failed or not self.results else 0
