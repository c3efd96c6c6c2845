from setuptools import setup

package_name = 'rwpend_sweep'

setup(
    name=package_name,
    version='0.1.0',
    packages=[package_name],
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
    ],
    install_requires=['setuptools'],
    extras_require={'cluster': ['dask[distributed]']},
    zip_safe=False,
    description='Robustness studies: many closed-loop lockstep runs of the stack\'s own loop '
                '(scenario x axes), local processes or a Dask cluster; results, plots, ranking.',
    license='Apache-2.0',
)
