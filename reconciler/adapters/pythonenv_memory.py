"""The in-memory twin of `VenvPythonEnvs`, for fast tests of the planner and the steps.

No process and no file: `system` is what the system's interpreter already provides,
`available` what pip could install (name → version), and each environment is a dict of
what was installed into it. Locations are the real adapter's, so a plan names the same
folders either way. `calls` records every environment made and every pip run, the way a
test reads the apply log. The same contract suite (tests/contract/test_python_envs.py)
holds both to one behaviour.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from packaging.requirements import Requirement

from reconciler.adapters.pythonenv import PIP_HINT, env_name, satisfies
from reconciler.base.errors import DependencyError
from reconciler.engine.execution.ports import Log
from schemas.dependency import requirement_name


class MemoryPythonEnvs:
    """Environments as dicts; `calls` holds ("venv", (location,)) for each environment
    made and ("pip", requirements) for each pip run."""

    def __init__(self, available: dict[str, str] | None = None,
                 system: dict[str, str] | None = None, *,
                 base: Path = Path("/var/lib/lpam/venvs")) -> None:
        self.available = {} if available is None else available
        self.system = {} if system is None else system
        self.base = base
        self.envs: dict[Path, dict[str, str]] = {}  # location → name → version installed
        self.marked: set[Path] = set()
        self.calls: list[tuple[str, tuple[str, ...]]] = []

    def location(self, requirements: Sequence[str]) -> Path:
        return self.base / env_name(requirements)

    def ready(self, requirements: Sequence[str]) -> bool:
        return self.location(requirements) in self.marked

    def unsatisfied(self, requirements: Sequence[str]) -> list[str]:
        env = self.location(requirements)
        return self._lacking(requirements, self.envs[env] if env in self.marked else {})

    def ensure(self, requirements: Sequence[str], *, log: Log) -> Path:
        env = self.location(requirements)
        if env not in self.marked:
            self.envs[env] = {}
            self.calls.append(("venv", (str(env),)))
            log(f"venv {env}")
        missing = self._lacking(requirements, self.envs[env])
        if missing:
            self.calls.append(("pip", tuple(missing)))
            log(f"pip install {' '.join(missing)}")
            absent = [text for text in missing
                      if not satisfies(Requirement(text), self._available(text))]
            if absent:
                raise DependencyError(
                    f"pip could not install {', '.join(missing)}: No matching distribution "
                    f"found for {absent[0]}", details=[f"pip install {' '.join(missing)}"],
                    hint=PIP_HINT,
                )
            for text in missing:
                self.envs[env][requirement_name(text)] = str(self._available(text))
        self.marked.add(env)
        return env

    def collect(self, keep: set[Path]) -> None:
        for env in [env for env in self.envs if env not in keep]:
            del self.envs[env]
            self.marked.discard(env)

    def _available(self, text: str) -> str | None:
        return {requirement_name(k): v for k, v in self.available.items()}.get(
            requirement_name(text))

    def _lacking(self, requirements: Sequence[str], env: dict[str, str]) -> list[str]:
        """The environment's own installs shadow the system's, as its site-packages does."""
        seen = {**{requirement_name(k): v for k, v in self.system.items()}, **env}
        return [text for text in requirements
                if not satisfies(Requirement(text), seen.get(requirement_name(text)))]
