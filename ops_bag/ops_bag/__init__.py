"""rosbag2 bags in MCAP, written and read with the ``mcap`` library (see README.md)."""

from .reader import BagReader, BagReadError
from .writer import BagExistsError, BagWriteError, BagWriter

__all__ = ["BagExistsError", "BagReadError", "BagReader", "BagWriteError", "BagWriter"]
