"""Small URDFs shipped with the package (articulated task objects): ``path(name)`` finds one."""

from pathlib import Path


def path(name: str) -> str:
    return str(Path(__file__).with_name(name))
