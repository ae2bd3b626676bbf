"""Print pip constraints pinning every dependency of pyproject.toml to its declared lower bound.

`make test-lowest` installs ocplace with them into a venv of its own and runs the smoke tests, so that each
lower bound in `[project.dependencies]` is a version the tests ran on (docs/install.md).
"""

import sys
import tomllib
from pathlib import Path

from packaging.requirements import Requirement

ROOT = Path(__file__).resolve().parent.parent


def lowest(requirements: list[str]) -> list[str]:
    """`name==lower` for each requirement with a `>=` bound (the others are left to the resolver)."""
    pins = []
    for text in requirements:
        requirement = Requirement(text)
        lower = [spec.version for spec in requirement.specifier if spec.operator in (">=", "==")]
        if lower:
            pins.append(f"{requirement.name}=={lower[0]}")
    return pins


def main() -> int:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    print("\n".join(lowest(project["dependencies"])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
