"""Package layout (everything else is in pyproject.toml).

The design card keeps Prefect flows and tasks and the data contracts in top-level folders; they install as
subpackages of ``hadal`` (``hadal.flows``, ``hadal.tasks``, ``hadal.schemas``) so the distribution does not
claim the global module names ``flows``, ``tasks`` or ``schemas``.
"""

from setuptools import find_packages, setup

setup(
    packages=[*find_packages("src"), "hadal.flows", "hadal.tasks", "hadal.schemas"],
    package_dir={"": "src", "hadal.flows": "flows", "hadal.tasks": "tasks", "hadal.schemas": "schemas"},
)
