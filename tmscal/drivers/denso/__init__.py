"""DENSO robots over b-CAP: ``variant`` (VARIANT types and codec), ``hresult`` (HRESULT
codes and names), ``packet`` (function IDs, packets, stream framer), ``client`` (BCAPClient:
connection, request/reply) and ``robot`` (DensoRobot, the tmscal driver)."""
