from glob import glob

from setuptools import find_packages, setup

package_name = "katana_bringup"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config",
         glob("config/*.yaml") + glob("config/*.json") + glob("config/*.rviz")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Katana curiosity maintainers",
    maintainer_email="katana-curiosity@example.org",
    description="Launch files, parameters and the all-in-one runner.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "katana-run = katana_bringup.run:main",
            "katana-demo = katana_bringup.demo:main",
            "katana-play = katana_bringup.play:main",
            "run_recorder = katana_bringup.recorder_node:main",
            "foxglove_bridge = katana_bringup.foxglove_bridge:main",
        ],
    },
)
