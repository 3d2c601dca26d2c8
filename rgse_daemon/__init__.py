"""RGSE daemon: in-line mass determination of spacecraft held by a KUKA KR C4 robot, automated."""

__version__ = "0.1.0"
