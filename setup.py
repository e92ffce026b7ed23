"""Package layout (metadata, dependencies and scripts are in pyproject.toml).

The repository keeps agents/, train/, benchmarks/ and configs/ at its top level; a
wheel installs them as snake_env.agents, snake_env.train, snake_env.benchmarks and the
package data snake_env.configs, so only ``snake_env`` lands at the top of
site-packages (top-level ``agents`` or ``train`` packages clash with other
distributions). ``pip install -e .`` maps the same names onto the folders.
"""

from setuptools import find_packages, setup

FOLDERS = {"snake_env": "snake_env", "snake_env.agents": "agents", "snake_env.train": "train",
           "snake_env.benchmarks": "benchmarks"}

packages = ["snake_env.configs"]
for name, folder in FOLDERS.items():
    packages += [name] + [f"{name}.{sub}" for sub in find_packages(folder)]

setup(
    packages=packages,
    package_dir={**FOLDERS, "snake_env.configs": "configs"},
    package_data={"snake_env.configs": ["*.yaml"]},
)
