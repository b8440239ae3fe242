"""World and hardware simulators."""

from jaxnav.sim import ir_receiver as ir_receiver
from jaxnav.sim import landmark_world as landmark_world
from jaxnav.sim import tag_carpet as tag_carpet
from jaxnav.sim import uhf_reader as uhf_reader
