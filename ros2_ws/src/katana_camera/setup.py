from glob import glob

from setuptools import find_packages, setup

package_name = "katana_camera"

setup(
    name=package_name,
    version="0.1.0",
    packages=find_packages(exclude=["test"]),
    data_files=[
        ("share/ament_index/resource_index/packages", ["resource/" + package_name]),
        ("share/" + package_name, ["package.xml"]),
        ("share/" + package_name + "/config", glob("config/*.yaml")),
    ],
    install_requires=["setuptools"],
    zip_safe=True,
    maintainer="Katana curiosity maintainers",
    maintainer_email="katana-curiosity@example.org",
    description="The real overhead camera through OpenCV (camera_node) and its camera_info core.",
    license="Apache-2.0",
    entry_points={
        "console_scripts": [
            "camera_node = katana_camera.camera_node:main",
        ],
    },
)
