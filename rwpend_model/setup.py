from setuptools import setup

package_name = 'rwpend_model'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    package_data={package_name: ['config/*.yaml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', ['rwpend_model/config/rig.yaml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    description='rwpend pure core: rig parameters and plant model',
    license='Apache-2.0',
)
