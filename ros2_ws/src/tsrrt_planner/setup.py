"""Build script of the tsrrt_planner ament_python package."""

import os
from glob import glob
from pathlib import Path

from setuptools import find_packages, setup

package_name = 'tsrrt_planner'
here = Path(__file__).resolve().parent

# YAML files inside the python package (e.g. scenarios/) ship with it, relative to the package.
package_yaml = sorted(
    str(p.relative_to(here / package_name)) for p in (here / package_name).rglob('*.yaml')
)

data_files = [
    ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
    ('share/' + package_name, ['package.xml']),
]
# Node parameter files, found by ament_index_python.get_package_share_directory(). isfile()
# skips the dangling links that --symlink-install leaves in build/ when a file is deleted.
config_yaml = sorted(f for f in glob('config/*.yaml') if os.path.isfile(f))
if config_yaml:
    data_files.append(('share/' + package_name + '/config', config_yaml))

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test']),
    package_data={package_name: package_yaml},
    data_files=data_files,
    install_requires=['setuptools'],
    zip_safe=False,
    maintainer='tsrrt maintainers',
    maintainer_email='maintainers@tsrrt.dev',
    description='Task-space region RRT planner (Scholz and Stilman 2010) as a ROS 2 node.',
    license='Apache-2.0',
    tests_require=['pytest'],
    entry_points={
        'console_scripts': [
            'planner_node = tsrrt_planner.planner_node:main',
        ],
    },
)
