"""The ``unitree_api`` request / response messages of Unitree's services (RPC over DDS).

Written from Unitree's public IDL (``unitree_api/msg/Request_.idl``, ``Response_.idl`` and their
headers, as unitree_sdk2 ships them): same type names, members and order. A client writes a
:class:`Request_` on ``rt/api/<service>/request`` (``identity.id`` a fresh number,
``identity.api_id`` the call, ``parameter`` JSON text) and reads the :class:`Response_` with the
same ``identity`` on ``rt/api/<service>/response`` (``status.code`` 0: success, ``data`` JSON).
"""

# no ``from __future__ import annotations``: Cyclone DDS reads the member types at run time
from dataclasses import dataclass, field

import cyclonedds.idl.types as types
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.annotations import autoid, final


@dataclass
@final
@autoid("sequential")
class RequestIdentity_(IdlStruct, typename="unitree_api.msg.dds_.RequestIdentity_"):
    id: types.int64 = 0
    api_id: types.int64 = 0


@dataclass
@final
@autoid("sequential")
class RequestLease_(IdlStruct, typename="unitree_api.msg.dds_.RequestLease_"):
    id: types.int64 = 0


@dataclass
@final
@autoid("sequential")
class RequestPolicy_(IdlStruct, typename="unitree_api.msg.dds_.RequestPolicy_"):
    priority: types.int32 = 0
    noreply: bool = False


@dataclass
@final
@autoid("sequential")
class RequestHeader_(IdlStruct, typename="unitree_api.msg.dds_.RequestHeader_"):
    identity: RequestIdentity_ = field(default_factory=RequestIdentity_)
    lease: RequestLease_ = field(default_factory=RequestLease_)
    policy: RequestPolicy_ = field(default_factory=RequestPolicy_)


@dataclass
@final
@autoid("sequential")
class Request_(IdlStruct, typename="unitree_api.msg.dds_.Request_"):
    header: RequestHeader_ = field(default_factory=RequestHeader_)
    parameter: str = ""
    binary: types.sequence[types.uint8] = field(default_factory=list)


@dataclass
@final
@autoid("sequential")
class ResponseStatus_(IdlStruct, typename="unitree_api.msg.dds_.ResponseStatus_"):
    code: types.int32 = 0


@dataclass
@final
@autoid("sequential")
class ResponseHeader_(IdlStruct, typename="unitree_api.msg.dds_.ResponseHeader_"):
    identity: RequestIdentity_ = field(default_factory=RequestIdentity_)
    status: ResponseStatus_ = field(default_factory=ResponseStatus_)


@dataclass
@final
@autoid("sequential")
class Response_(IdlStruct, typename="unitree_api.msg.dds_.Response_"):
    header: ResponseHeader_ = field(default_factory=ResponseHeader_)
    data: str = ""
    binary: types.sequence[types.uint8] = field(default_factory=list)
