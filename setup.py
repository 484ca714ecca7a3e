"""ament_python build of mr_suspension (also installable with pip into a virtual environment)."""

from glob import glob
import os

from setuptools import find_packages, setup

PACKAGE = 'mr_suspension'
NODES = ['plant', 'controller', 'actuator', 'recorder', 'replay', 'full_car_plant',
         'modal_controller', 'full_car_composed']

setup(
    name=PACKAGE,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + PACKAGE]),
        ('share/' + PACKAGE, ['package.xml']),
    ] + [
        (os.path.join('share', PACKAGE, os.path.dirname(d)), glob(d + '*.yaml'))
        for d in sorted(glob('config/*/'))
    ] + [
        (os.path.join('share', PACKAGE, 'config'), ['config/fastdds.xml']),
        (os.path.join('share', PACKAGE, 'msg_defs'), glob('msg_defs/*.yaml')),
        (os.path.join('share', PACKAGE, 'launch'), glob('launch/*.launch.py')),
    ],
    install_requires=['setuptools', 'numpy', 'scipy', 'numba', 'PyYAML', 'matplotlib',
                      'scikit-learn'],
    zip_safe=False,
    maintainer='mr_suspension maintainers',
    maintainer_email='maintainers@mr-suspension.invalid',
    description='Semi-active MR-damper quarter-car suspension: ROS 2 nodes, simulator, diagnosis.',
    license='Apache-2.0',
    entry_points={
        'console_scripts': ['mr-suspension = mr_suspension.cli:main'] + [
            f'{name} = {PACKAGE}.nodes.{name}:main' for name in NODES],
    },
)
