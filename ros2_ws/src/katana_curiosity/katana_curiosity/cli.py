"""Command line entry point (placeholder until the experiments module lands)."""


def main() -> None:
    raise SystemExit("katana-curiosity: not built yet")
