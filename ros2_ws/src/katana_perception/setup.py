from setuptools import find_packages, setup

package_name = "katana_perception"

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
    description="Katana blocks-world perception: segmentation, calibration, memory, fovea, judge.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "perception_node = katana_perception.perception_node:main",
            "block_memory_node = katana_perception.block_memory_node:main",
            "fovea_node = katana_perception.fovea_node:main",
            "katana-calibrate = katana_perception.calibrate_cli:main",
        ],
    },
)
