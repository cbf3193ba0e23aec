"""volrender: OpenCL volume and molten-glass renderer."""
__version__ = "0.1.0"
