from setuptools import setup

package_name = 'rwpend_ros'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    package_data={package_name: ['fastdds_udp_localhost.xml']},
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    description='Thin ROS glue shared by the rwpend nodes.',
    license='Apache-2.0',
)
