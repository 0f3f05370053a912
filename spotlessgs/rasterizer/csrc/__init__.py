"""C++ sources of the CPU kernels; a package only so that the sources ship in wheels (package data *.cpp)."""
