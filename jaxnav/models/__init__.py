"""Pure sensor and motion models."""

from jaxnav.models import hf_rfid as hf_rfid
from jaxnav.models import ir as ir
from jaxnav.models import landmarks as landmarks
from jaxnav.models import motion as motion
from jaxnav.models import sensor as sensor
from jaxnav.models import uhf_rfid as uhf_rfid
