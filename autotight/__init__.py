"""autotight: find the redundant constraints that make Shor's SDP relaxation tight."""

__version__ = "0.1.0"
