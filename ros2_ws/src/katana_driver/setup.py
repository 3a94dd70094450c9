from glob import glob

from setuptools import find_packages, setup

package_name = "katana_driver"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
        ("share/" + package_name + "/launch", glob("launch/*.launch.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Katana curiosity maintainers",
    maintainer_email="katana-curiosity@example.org",
    description="Katana protocol driver (katana_driver_node).",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "katana_driver_node = katana_driver.katana_driver_node:main",
        ],
    },
)
