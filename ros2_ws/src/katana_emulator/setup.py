from setuptools import find_packages, setup

package_name = "katana_emulator"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Katana curiosity maintainers",
    maintainer_email="katana-curiosity@example.org",
    description="Protocol-level Katana controller emulator for tests and dry runs (never an arm).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "katana-emulator = katana_emulator.emulator:main",
        ],
    },
)
