"""The ``unitree_api`` request / response messages of Unitree's services (RPC over DDS).

Written from Unitree's public IDL (``unitree_api/msg/Request_.idl``, ``Response_.idl`` and their
headers, as unitree_sdk2 ships them): same type names, members and order; built from the member
tables below by :class:`sim2real.deploy.backends.unitree.idl.Package`. A client writes a
:class:`Request_` on ``rt/api/<service>/request`` (``identity.id`` a fresh number,
``identity.api_id`` the call, ``parameter`` JSON text) and reads the :class:`Response_` with the
same ``identity`` on ``rt/api/<service>/response`` (``status.code`` 0: success, ``data`` JSON).
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the member types at run time
import cyclonedds.idl.types as types

from sim2real.deploy.backends.unitree.idl import Package

_api = Package("unitree_api", __name__)
_BINARY = ("binary", types.sequence[types.uint8])

RequestIdentity_ = _api.struct("RequestIdentity_", [("id", types.int64), ("api_id", types.int64)])
RequestLease_ = _api.struct("RequestLease_", [("id", types.int64)])
RequestPolicy_ = _api.struct("RequestPolicy_", [("priority", types.int32), ("noreply", bool)])
RequestHeader_ = _api.struct(
    "RequestHeader_",
    [("identity", RequestIdentity_), ("lease", RequestLease_), ("policy", RequestPolicy_)],
)
Request_ = _api.struct("Request_", [("header", RequestHeader_), ("parameter", str), _BINARY])
ResponseStatus_ = _api.struct("ResponseStatus_", [("code", types.int32)])
ResponseHeader_ = _api.struct(
    "ResponseHeader_", [("identity", RequestIdentity_), ("status", ResponseStatus_)]
)
Response_ = _api.struct("Response_", [("header", ResponseHeader_), ("data", str), _BINARY])
