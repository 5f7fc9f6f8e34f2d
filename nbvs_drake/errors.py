"""User-facing errors: each one names the problem in one line (the CLI prints it without a
traceback); and `quiet_library_logs`, which keeps the libraries' notes off the user's screen."""


class NbvsError(Exception):
    """Base class for errors caused by the user's input (scenario, meshes, parameters)."""


class ScenarioError(NbvsError):
    """A scenario file is malformed or holds impossible parameters."""


class MeshError(NbvsError):
    """An object mesh is missing, unreadable or empty."""


class RunExistsError(NbvsError):
    """The output folder holds a finished run (its summary.json) and overwriting was not asked
    for, or another run is writing it (its lock), or it cannot be made."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a run or a batch, with a line that says where what was finished is."""


class InterruptGuard:
    """Knows whether Ctrl-C arrived while it was active, whatever became of the KeyboardInterrupt.

    A SIGINT that lands inside an import of a compiled module (Open3D, Drake) or a callback from
    C++ can surface as another exception (`ImportError: initialization failed`). Inside
    `with InterruptGuard() as g:` the SIGINT handler notes the signal before it raises
    KeyboardInterrupt, so that `g.interrupted` tells the caller to report an interruption and
    not the exception it turned into. It installs itself only in the main thread and only over
    Python's default handler (a caller's own handler is left alone)."""

    def __init__(self):
        self.interrupted = False
        self._old = None

    def _on_sigint(self, signum, frame):
        self.interrupted = True
        raise KeyboardInterrupt

    def __enter__(self):
        import signal
        import threading
        if threading.current_thread() is threading.main_thread() and \
                signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._old = signal.signal(signal.SIGINT, self._on_sigint)
        return self

    def __exit__(self, *exc):
        if self._old is not None:
            import signal
            signal.signal(signal.SIGINT, self._old)
        return False

    def was_interrupt(self, exc: BaseException) -> bool:
        """Whether `exc` is Ctrl-C, or what Ctrl-C turned into."""
        return isinstance(exc, KeyboardInterrupt) or self.interrupted


def quiet_library_logs():
    """Silences what is not for the user, quiet or not: Drake's INFO lines (context
    parallelism, once per plan's collision checker; the replay's own Meshcat) and numba's note
    that it falls back from an old TBB to another threading layer."""
    import logging
    import warnings

    import pydrake  # noqa: F401  (it sets the "drake" logger's level when first imported)
    logging.getLogger("drake").setLevel(logging.WARNING)
    warnings.filterwarnings("ignore", message="The TBB threading layer requires")
