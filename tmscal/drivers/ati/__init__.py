"""ATI Net F/T force-torque sensors over RDT (UDP): ``codec`` (bytes) and ``sensor``
(``ATINetFT``, the driver)."""
