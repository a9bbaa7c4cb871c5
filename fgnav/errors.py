"""Errors a user can cause (bad input, unobservable problem); the CLI prints them and exits 2."""


class UserError(ValueError):
    """A problem with the user's input or request: printed without a traceback, exit code 2."""


class InputFormatError(UserError):
    """A file does not follow its documented format.

    The message names the file, the line (1-based), the column and what was expected.
    """

    def __init__(self, path, line, column, expected, found=None):
        self.path, self.line, self.column, self.expected, self.found = path, line, column, expected, found
        where = f"{path}"
        if line is not None:
            where += f", line {line}"
        if column:
            where += f", column '{column}'"
        msg = f"{where}: expected {expected}"
        if found is not None:
            msg += f", found {found!r}"
        super().__init__(msg)


class NotObservableError(UserError):
    """The measurements cannot determine the requested states; the message says which."""
