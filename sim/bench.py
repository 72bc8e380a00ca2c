"""q3t bench (filled in below)."""


def add_parser(sub) -> None:
    pass
