"""Write requirements.lock: exact pins of every distribution pip installed in .venv.

`pip freeze` also lists the `*.egg-info` folders the ros-* wheels carry inside them
(e.g. `rclpy==7.1.5` inside ros-rclpy); those are no PyPI projects and break a fresh
install, so only real `.dist-info` installs are pinned.
"""
import importlib.metadata
import pathlib
import re
import sys

HEADER = """# Exact pins of every package in .venv (Python 3.11, Debian 12, x86_64).
# Generated from requirements.in by 'make lock'; 'make setup' installs exactly this.
"""

def _key(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def pin_reasons(requirements_in: pathlib.Path) -> dict:
    """{project: comment} for requirements.in lines with a trailing `# why` (e.g. why a
    version is held back), so the lock keeps saying why after every `make lock`."""
    reasons = {}
    if requirements_in.exists():
        for line in requirements_in.read_text().splitlines():
            spec, _, why = line.partition(" #")
            name = re.match(r"\s*([A-Za-z0-9_.-]+)", spec)
            if name and why.strip():
                reasons[_key(name.group(1))] = why.strip()
    return reasons


def main(path: str) -> int:
    reasons = pin_reasons(pathlib.Path(path).with_name("requirements.in"))
    pins = set()
    for dist in importlib.metadata.distributions():
        location = str(getattr(dist, "_path", ""))
        if location.endswith(".dist-info") and dist.read_text("INSTALLER") in ("pip\n", "pip"):
            name = dist.metadata["Name"]
            if name == "pip":
                continue
            why = reasons.get(_key(name))
            pins.add(f"{name}=={dist.version}" + (f"  # {why.lstrip('# ')}" if why else ""))
    with open(path, "w") as f:
        f.write(HEADER + "\n".join(sorted(pins, key=str.lower)) + "\n")
    print(f"write_lock: {len(pins)} pins -> {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
