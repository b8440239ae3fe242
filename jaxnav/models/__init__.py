"""Pure sensor and motion models."""

from jaxnav.models import hf_rfid as hf_rfid, ir as ir, landmarks as landmarks, motion as motion, uhf_rfid as uhf_rfid
