from setuptools import setup

package_name = 'rwpend_loop'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    zip_safe=False,
    description='The loop: hardware read -> estimator -> controller -> command gate -> hardware write, '
                'in one thread, with the plant, estimator and controller nodes hosted around it.',
    license='Apache-2.0',
)
