"""USB descriptors as pyusb reads them: the device and bulk-endpoint descriptors an emulated
device presents (USB 2.0 specification, chapter 9: standard descriptors).

Kept apart from the bus (`normbox_lab.sim.usb`) so that a device module builds its
descriptors without importing the bus that plugs it in."""

from __future__ import annotations

from typing import Any


class Descriptor:
    """A USB descriptor: its fields as attributes (what pyusb reads with getattr)."""

    def __init__(self, **fields: Any) -> None:
        self.__dict__.update(fields)
        self.extra_descriptors = fields.get("extra_descriptors", [])

    def __repr__(self) -> str:
        return f"Descriptor({self.__dict__!r})"


def device_descriptor(vendor_id: int, product_id: int, *, bcd_device: int = 0x0100,
                      max_packet_size0: int = 64) -> Descriptor:
    return Descriptor(bLength=18, bDescriptorType=0x01, bcdUSB=0x0200, bDeviceClass=0x00,
                      bDeviceSubClass=0x00, bDeviceProtocol=0x00,
                      bMaxPacketSize0=max_packet_size0, idVendor=vendor_id, idProduct=product_id,
                      bcdDevice=bcd_device, iManufacturer=1, iProduct=2, iSerialNumber=3,
                      bNumConfigurations=1, address=None, bus=None, port_number=None,
                      port_numbers=None, speed=None)


def bulk_endpoint(address: int, max_packet_size: int = 512) -> Descriptor:
    return Descriptor(bLength=7, bDescriptorType=0x05, bEndpointAddress=address,
                      bmAttributes=0x02, wMaxPacketSize=max_packet_size, bInterval=0,
                      bRefresh=0, bSynchAddress=0)


__all__ = ["Descriptor", "bulk_endpoint", "device_descriptor"]
