"""Errors that name the file, the field and the problem."""


class DataError(ValueError):
    """Bad input data: says which file, which field and what is wrong.

    Parameters
    ----------
    problem : str
        What is wrong, in words a user can act on.
    path : str or os.PathLike, optional
        The file (or ``"demo"``) the data came from.
    field : str, optional
        The variable, coordinate or parameter at fault.
    """

    def __init__(self, problem, *, path=None, field=None):
        self.problem = problem
        self.path = None if path is None else str(path)
        self.field = field
        parts = []
        if self.path:
            parts.append(self.path)
        if field:
            parts.append(f"field '{field}'")
        prefix = ": ".join(parts)
        super().__init__(f"{prefix}: {problem}" if prefix else problem)


class UsageError(ValueError):
    """A bad command-line value, found before any work starts (the ``nephele`` CLI exits 2 with its line)."""
