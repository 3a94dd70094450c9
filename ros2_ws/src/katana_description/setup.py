from glob import glob

from setuptools import find_packages, setup

package_name = "katana_description"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/urdf", glob("urdf/*.urdf")),
        ("share/" + package_name + "/launch", glob("launch/*.py")),
        ("share/" + package_name + "/rviz", glob("rviz/*.rviz")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Katana curiosity maintainers",
    maintainer_email="katana-curiosity@example.org",
    description="URDF of the Katana arm, table and blocks, and the frame publisher.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "katana-urdf-gen = katana_description.urdf_gen:main",
            "frame_publisher = katana_description.frame_publisher:main",
        ],
    },
)
