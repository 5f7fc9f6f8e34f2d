"""User-facing errors: each one names the problem in one line (the CLI prints it without a traceback)."""


class NbvsError(Exception):
    """Base class for errors caused by the user's input (scenario, meshes, parameters)."""


class ScenarioError(NbvsError):
    """A scenario file is malformed or holds impossible parameters."""


class MeshError(NbvsError):
    """An object mesh is missing, unreadable or empty."""


class RunExistsError(NbvsError):
    """The output folder holds a finished run (its summary.json) and overwriting was not asked for."""


class Interrupted(KeyboardInterrupt):
    """Ctrl-C during a run or a batch, with a line that says where what was finished is."""
