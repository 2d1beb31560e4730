"""One exception hierarchy, so callers can catch everything tsrrt raises on bad input."""


class TsrrtError(Exception):
    """Base of every error tsrrt raises deliberately."""


class ScenarioError(TsrrtError):
    """A scenario file is malformed; the message names the file, the field and the problem."""

    def __init__(self, source: str, field: str, problem: str) -> None:
        self.source = source
        self.field = field
        self.problem = problem
        super().__init__(f"{source}: {field}: {problem}")


class ClassTableError(TsrrtError):
    """The object class table is malformed or a class name is unknown."""


class RobotModelError(TsrrtError):
    """The robot description could not be found or generated."""
