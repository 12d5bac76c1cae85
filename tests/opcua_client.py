"""An independent OPC UA client (Python asyncua) for falc-opcua's tests and
benchmark. It prints one JSON object per line on stdout; the Rust side
asserts on them.

  opcua_client.py scenario URL CREDENTIALS_DIR WORK_DIR
      the acceptance walk: an untrusted client certificate refused, then
      admitted (rejected/ -> trusted/, as the install guide says); browse;
      subscribe; an alarm event (after printing "listening"), Acknowledge
      (after a line on stdin); AddOrder dikdroog, Start, Answer "ja" to the question,
      the order done and the state back to Idle; the observer may read but
      not Start; a wrong password and an anonymous session refused.
  opcua_client.py user-cert - - WORK_DIR
      makes an X.509 user certificate (WORK_DIR/user-cert.der).
  opcua_client.py by-certificate URL CREDENTIALS_DIR WORK_DIR
      logs in with that user certificate: reads, is refused Start (an
      observer); a certificate the users file does not name is refused.
  opcua_client.py order URL CREDENTIALS_DIR WORK_DIR
      one order through the methods (AddOrder dikdroog, Start, Answer "ja")
      to done and the state back to Idle.
  opcua_client.py plant URL CREDENTIALS_DIR WORK_DIR PLANT CELL OTHER
      a plant's gateway: browse the plant object FALC and cell CELL's
      object FALC.CELL; one order through CELL's own methods to done, cell
      OTHER's state watched meanwhile; the plant's orders with their cells.
  opcua_client.py conditions URL CREDENTIALS_DIR WORK_DIR
      Alarms & Conditions: the operator subscribes to conditions; the
      robot's emergency stop (pressed after "listening") seen as an active,
      unacknowledged condition; a late observer's ConditionRefresh sends
      it again, its Acknowledge is refused; the operator's is taken (after
      a line on stdin), and again refused as done; once the stop is
      released (another line) the condition is no longer retained, and an
      order runs to done.
  opcua_client.py machinery URL CREDENTIALS_DIR WORK_DIR
      the cells as machines of OPC 40001-1 Machinery, found by browse names
      and type definitions in the DI and Machinery namespaces only: each
      machine's Identification and its MachineryItemState and
      MachineryOperationMode (step "machines-N"), read again after each
      line on stdin.
  opcua_client.py mes URL CREDENTIALS_DIR WORK_DIR CELL JOB
      a manufacturing execution system nobody here wrote: finds machine
      CELL in Machinery's Machines folder and its JobManagement by browse
      names and type definitions of the Machinery, Job Management and
      ISA-95 namespaces only, loads ISA-95's data types from the server,
      reads the Identification and MachineryItemState, calls
      StoreAndStart with an ISA95JobOrderDataType for dikdroog (job order
      JOB), follows its state in JobOrderList to Ended (step "stored"
      after the call, "ended" at the end), reads its job response with
      RequestJobResponseByJobOrderID and JobOrderResponseList, the
      order's result (OPC 40001-101) with GetLatestResult and
      GetResultById and the ResultReadyEvent it heard; and the refusals:
      the same JobOrderID stored twice, an unknown one started, an unknown
      parameter, an observer's StoreAndStart.
  opcua_client.py job-states URL CREDENTIALS_DIR WORK_DIR CELL
      a job order's states through JobOrderControl's commands on the one
      cell CELL: one JobOrderID stored twice at once (one taken), two stored (NotAllowedToStart), one cancelled (gone), the
      other started (Running), paused (Interrupted: step mode), resumed
      (after a line on stdin) and aborted (Aborted); then the way back: a third StoreAndStart runs
      to Ended (the cell's question answered through FALC's Answer), and
      is cleared. Steps "stored", "cancelled", "paused", "aborted",
      "ended", each with the ReturnStatus of its calls.
  opcua_client.py siege URL CREDENTIALS_DIR WORK_DIR ATTACKER N
      N wrong passwords for user `opcua` from address ATTACKER (a second
      loopback address) while the real `opcua` logs in from 127.0.0.1 once
      a second, each login timed; how the attacker was refused.
  opcua_client.py watch URL CREDENTIALS_DIR WORK_DIR NODE...
      prints every data change of the nodes (FALC.* ids) with the time it
      arrived, until a line (or the end) on stdin.
"""

import asyncio
import contextvars
import json
import shutil
import socket
import sys
import time
import tomllib
from pathlib import Path

from asyncua import Client, ua
from asyncua.common.events import get_filter_from_event_type
from asyncua.crypto.cert_gen import setup_self_signed_certificate
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from cryptography.x509.oid import ExtendedKeyUsageOID

APP_URI = "urn:falc:test-client"


def say(**what):
    print(json.dumps(what), flush=True)


def users(credentials_dir: Path) -> dict:
    text = (credentials_dir / "opcua-users.toml").read_text()
    return {u["name"]: u.get("password", "") for u in tomllib.loads(text)["user"]}


async def certificate(work: Path):
    key, cert = work / "client-key.pem", work / "client-cert.der"
    if not cert.exists():
        await setup_self_signed_certificate(
            key, cert, APP_URI, socket.gethostname(),
            [ExtendedKeyUsageOID.CLIENT_AUTH],
            {"countryName": "NL", "organizationName": "FALC", "commonName": "falc-test-client"},
        )
    return key, cert


async def client(url, work, user=None, password=None, secure=True) -> Client:
    c = Client(url, timeout=10)
    c.application_uri = APP_URI
    if user is not None:
        c.set_user(user)
        c.set_password(password)
    if secure:
        key, cert = await certificate(work)
        await c.set_security(
            SecurityPolicyBasic256Sha256, certificate=str(cert), private_key=str(key),
            mode=ua.MessageSecurityMode.SignAndEncrypt,
        )
    return c


async def connect(url, work, user, password, secure=True) -> Client:
    """Connects, retrying while the gateway is still starting."""
    end = time.monotonic() + 20
    while True:
        c = await client(url, work, user, password, secure)
        try:
            await c.connect()
            return c
        except (ConnectionError, OSError, asyncio.TimeoutError):
            if time.monotonic() > end:
                raise
            await asyncio.sleep(0.2)


class Changes:
    """Data changes and events, as they arrive."""

    def __init__(self):
        self.queue = asyncio.Queue()
        self.events = []

    def datachange_notification(self, node, val, data):
        self.queue.put_nowait((node.nodeid.Identifier, val, time.time()))

    def event_notification(self, event):
        self.events.append(str(event.Message.Text))

    async def until(self, seen: dict, pred, limit: float):
        end = time.monotonic() + limit
        while not pred(seen):
            left = end - time.monotonic()
            if left <= 0:
                return False
            try:
                ident, val, _ = await asyncio.wait_for(self.queue.get(), left)
            except asyncio.TimeoutError:
                return False
            seen.setdefault(ident, []).append(val)
        return True


async def until_event(changes, text: str, limit: float):
    """The first event whose message starts with `text`, within `limit` s."""
    end = time.monotonic() + limit
    while time.monotonic() < end:
        for e in changes.events:
            if e.startswith(text):
                return e
        await asyncio.sleep(0.05)
    return None


async def admit(url, creds: Path, work: Path):
    """Connects with a new client certificate: refused, it lands in the
    gateway's rejected/ directory; moved to trusted/ (what an administrator
    does), it is admitted. Whether it was refused, and how many files moved."""
    pw = users(creds)
    pki = creds / "opcua-pki"
    refused = None
    end = time.monotonic() + 20
    while refused is None:
        c = await client(url, work, "console", pw["console"])
        try:
            await c.connect()
            await c.disconnect()
            refused = "no"
        except ua.UaStatusCodeError as e:
            refused = type(e).__name__
        except (ConnectionError, OSError, asyncio.TimeoutError):
            if time.monotonic() > end:
                raise
            await asyncio.sleep(0.2)
    rejected = list((pki / "rejected").glob("*.der"))
    (pki / "trusted").mkdir(exist_ok=True)
    for f in rejected:
        shutil.move(str(f), str(pki / "trusted" / f.name))
    return refused, len(rejected)


WATCHED = ["PackMLState", "Question", "Orders.Ids", "Orders.States",
           "CellRecipeState", "Stations.welding.RobotState",
           "Stations.cell.RecipeStatus"]


async def subscribe(c, ns, falc, root="FALC", more=()):
    """Subscribes to the WATCHED values of cell object `root` (and the
    nodes `more`) and the cell's events; returns the changes and the values
    seen so far (the first of each)."""
    changes = Changes()
    sub = await c.create_subscription(50, changes)
    # Sampling interval 0: every value the gateway writes. With asyncua's
    # default (50 ms) a state shorter than that (Held, when a question is
    # asked and answered within 50 ms at time scale 50) is sampled away.
    ids = [f"{root}.{i}" for i in WATCHED] + list(more)
    await sub.subscribe_data_change(
        [c.get_node(ua.NodeId(i, ns)) for i in ids], sampling_interval=0.0
    )
    await sub.subscribe_events(falc)
    seen = {}
    await changes.until(seen, lambda s: all(i in s for i in ids), 10)
    return changes, seen


async def run_order(falc, ns, changes, seen, root="FALC"):
    """AddOrder dikdroog, Start, Answer "ja" to the question when it is
    notified, until the order is done and the state back to Idle: through
    the methods of cell object `root`."""
    k = lambda n: f"{root}.{n}"
    order = await falc.call_method(f"{ns}:AddOrder", "dikdroog")
    say(step="added", order=order)
    await falc.call_method(f"{ns}:Start")
    asked = await changes.until(seen, lambda s: any(q for q in s.get(k("Question"), [])), 120)
    question = next((q for q in seen.get(k("Question"), []) if q), None)
    say(step="question", asked=asked, question=question)
    answered = await falc.call_method(f"{ns}:Answer", "ja")
    say(step="answered", reply=answered)

    def done(s):
        ids = s.get(k("Orders.Ids"), [[]])[-1]
        states = s.get(k("Orders.States"), [[]])[-1]
        mine = dict(zip(ids, states)).get(int(order))
        return mine == "done" and s.get(k("PackMLState"), [""])[-1] == "Idle"

    ended = await changes.until(seen, done, 180)
    ids = seen.get(k("Orders.Ids"), [[]])[-1]
    states = seen.get(k("Orders.States"), [[]])[-1]
    say(step="ended", ended=ended, order_state=dict(zip(map(str, ids), states)).get(str(order)),
        states=seen.get(k("PackMLState"), []),
        recipe_states=sorted(set(seen.get(k("CellRecipeState"), []))))
    return order


async def plant(url, creds: Path, work: Path, name, cell, other):
    """A plant's gateway: the plant object and a cell's, one order through
    the cell's own methods while the other cell is watched."""
    pw = users(creds)
    await admit(url, creds, work)
    c = await connect(url, work, "console", pw["console"])
    ns = await c.get_namespace_index(f"urn:falc:{name}")
    falc = await c.nodes.objects.get_child([f"{ns}:FALC"])
    plant_names = sorted([(await n.read_browse_name()).Name for n in await falc.get_children()])
    mine = await falc.get_child([f"{ns}:{cell}"])
    cell_names = sorted([(await n.read_browse_name()).Name for n in await mine.get_children()])
    node = lambda i: c.get_node(ua.NodeId(i, ns))
    say(step="browse", plant=plant_names, cell=cell_names,
        cells=await node("FALC.Cells").read_value())
    root = f"FALC.{cell}"
    theirs = f"FALC.{other}.PackMLState"
    changes, seen = await subscribe(c, ns, mine, root, [theirs])
    say(step="subscribed", first={k: str(v[-1]) for k, v in seen.items()})
    order = await run_order(mine, ns, changes, seen, root)
    say(step="plant", other_states=seen.get(theirs, []),
        ids=await node("FALC.Orders.Ids").read_value(),
        cells=await node("FALC.Orders.Cells").read_value(),
        order=order,
        journal=await node(f"{root}.Journal.Texts").read_value(),
        other_journal=await node(f"FALC.{other}.Journal.Texts").read_value(),
        machines={k: v["states"]["item"]["state"] for k, v in (await machines(c)).items()})
    await c.disconnect()


async def as_operator(url, creds: Path, work: Path):
    """The client certificate admitted, a session of the operator user:
    the session, the namespace index and the cell object."""
    await admit(url, creds, work)
    c = await connect(url, work, "console", users(creds)["console"])
    ns = await c.get_namespace_index("urn:falc:falc1")
    return c, ns, await c.nodes.objects.get_child([f"{ns}:FALC"])


async def order(url, creds: Path, work: Path):
    """One order through the methods, as the operator user."""
    c, ns, falc = await as_operator(url, creds, work)
    changes, seen = await subscribe(c, ns, falc)
    await run_order(falc, ns, changes, seen)
    await c.disconnect()


async def scenario(url, creds: Path, work: Path):
    pw = users(creds)
    # 1. An unknown client certificate is refused and lands in rejected/.
    refused, files = await admit(url, creds, work)
    say(step="untrusted", refused=refused)
    say(step="admitted", files=files)

    # 2. Browse as the operator.
    c = await connect(url, work, "console", pw["console"])
    ns = await c.get_namespace_index("urn:falc:falc1")
    falc = await c.nodes.objects.get_child([f"{ns}:FALC"])
    names = sorted([(await n.read_browse_name()).Name for n in await falc.get_children()])
    stations = await falc.get_child([f"{ns}:Stations"])
    station_names = sorted([(await n.read_browse_name()).Name for n in await stations.get_children()])
    welding = await stations.get_child([f"{ns}:welding"])
    welding_vars = sorted([(await n.read_browse_name()).Name for n in await welding.get_children()])
    transport = await stations.get_child([f"{ns}:transport"])
    transport_vars = sorted([(await n.read_browse_name()).Name for n in await transport.get_children()])
    say(step="browse", cell=names, stations=station_names, welding=welding_vars, transport=transport_vars)

    # 3. Subscribe to the cell's state, question and orders, and its events.
    node = lambda i: c.get_node(ua.NodeId(i, ns))
    changes, seen = await subscribe(c, ns, falc)
    say(step="subscribed", first={k: str(v[-1]) for k, v in seen.items()})

    # 4. An alarm (the test presses the robot's emergency stop when it reads
    # "listening") is an event; once the test says the stop is released,
    # Acknowledge clears the way, also an event.
    say(step="listening")
    raised = await until_event(changes, "alarm raised", 60)
    alarm = await node("FALC.Alarm").read_value()
    say(step="raised", event=raised, alarm=alarm, state=await node("FALC.PackMLState").read_value())
    loop = asyncio.get_running_loop()
    await loop.run_in_executor(None, sys.stdin.readline)
    reply = await falc.call_method(f"{ns}:Acknowledge", ua.Variant(0, ua.VariantType.Int64))
    acked = await until_event(changes, "alarm acknowledged", 20)
    await asyncio.sleep(0.5)
    say(step="acknowledged", reply=reply, event=acked, alarm=await node("FALC.Alarm").read_value())

    # 5. A refused method's words are in LastRefusal when it returns: read
    # at once, each time the newest refusal's.
    refusals = []
    for name in ["nosuch_a", "nosuch_b"]:
        try:
            await falc.call_method(f"{ns}:AddOrder", ua.Variant(name, ua.VariantType.String))
            code = None
        except ua.UaStatusCodeError as e:
            code = type(e).__name__
        refusals.append({"code": code, "last": await node("FALC.LastRefusal").read_value()})
    say(step="refusals", refusals=refusals)

    # 6. The way back: AddOrder, Start, Answer, done, back to Idle.
    await run_order(falc, ns, changes, seen)
    journal = await node("FALC.Journal.Texts").read_value()
    who = await node("FALC.Journal.Who").read_value()
    say(step="journal", texts=journal, who=who, events=changes.events)
    await c.disconnect()

    # 7. The observer reads but may not Start.
    o = await connect(url, work, "observer", pw["observer"])
    ns = await o.get_namespace_index("urn:falc:falc1")
    falc = await o.nodes.objects.get_child([f"{ns}:FALC"])
    state = await o.get_node(ua.NodeId("FALC.PackMLState", ns)).read_value()
    start = await falc.get_child([f"{ns}:Start"])
    executable = await start.read_attribute(ua.AttributeIds.UserExecutable)
    try:
        await falc.call_method(f"{ns}:Start")
        refused = None
    except ua.UaStatusCodeError as e:
        refused = type(e).__name__
    try:
        await o.get_node(ua.NodeId("FALC.Question", ns)).write_value("x")
        wrote = None
    except ua.UaStatusCodeError as e:
        wrote = type(e).__name__
    say(step="observer", state=state, user_executable=executable.Value.Value,
        start_refused=refused, write_refused=wrote)
    await o.disconnect()

    # 8. A wrong password, and no user at all, are refused.
    for user, password, what in [("console", "wrong", "wrong_password"), (None, None, "anonymous")]:
        try:
            x = await client(url, work, user, password)
            await x.connect()
            await x.disconnect()
            say(step=what, refused=None)
        except ua.UaStatusCodeError as e:
            say(step=what, refused=type(e).__name__)


async def user_cert(work: Path):
    """Makes an X.509 user certificate (for a users file entry)."""
    key, cert = work / "user-key.pem", work / "user-cert.der"
    await setup_self_signed_certificate(
        key, cert, "urn:falc:scada-user", socket.gethostname(),
        [ExtendedKeyUsageOID.CLIENT_AUTH],
        {"countryName": "NL", "organizationName": "FALC", "commonName": "scada"},
    )
    say(step="user_cert", der=str(cert))


async def by_certificate(url, creds: Path, work: Path):
    """Logs in with the user certificate instead of a password: reads,
    and is refused Start (the users file gives it role observer)."""
    await admit(url, creds, work)
    c = await client(url, work)
    await c.load_client_certificate(str(work / "user-cert.der"))
    await c.load_private_key(str(work / "user-key.pem"))
    await c.connect()
    ns = await c.get_namespace_index("urn:falc:falc1")
    falc = await c.nodes.objects.get_child([f"{ns}:FALC"])
    state = await c.get_node(ua.NodeId("FALC.PackMLState", ns)).read_value()
    try:
        await falc.call_method(f"{ns}:Start")
        refused = None
    except ua.UaStatusCodeError as e:
        refused = type(e).__name__
    await c.disconnect()
    # Another certificate than the users file names is refused.
    other = await client(url, work)
    await other.load_client_certificate(str(work / "client-cert.der"))
    await other.load_private_key(str(work / "client-key.pem"))
    try:
        await other.connect()
        await other.disconnect()
        stranger = None
    except ua.UaStatusCodeError as e:
        stranger = type(e).__name__
    say(step="by_certificate", state=state, start_refused=refused, stranger_refused=stranger)


async def throttle(url, creds: Path, work: Path, lockout: float):
    """Ten wrong passwords for `console` in a row, each timed; then the
    right one at once (locked), then after the lockout (logged in)."""
    await admit(url, creds, work)
    right = users(creds)["console"]

    async def attempt(password):
        began = time.monotonic()
        try:
            c = await client(url, work, "console", password)
            await c.connect()
            await c.disconnect()
            refused = None
        except Exception as e:  # the front refuses with an OPC UA Error message
            refused = type(e).__name__
        return refused, round((time.monotonic() - began) * 1000)

    wrong = [await attempt("wrong") for _ in range(10)]
    say(step="wrong", refused=[r for r, _ in wrong], ms=[m for _, m in wrong])
    locked, _ = await attempt(right)
    await asyncio.sleep(lockout + 0.5)
    after, _ = await attempt(right)
    say(step="locked", locked=locked, after=after)


ACKNOWLEDGE = ua.NodeId(ua.ObjectIds.AcknowledgeableConditionType_Acknowledge)


class ConditionEvents:
    """The condition events of a subscription, as plain values."""

    def __init__(self):
        self.seen = []

    def event_notification(self, e):
        g = lambda n: getattr(e, n, None)
        message = g("Message")
        self.seen.append({
            "condition": g("NodeId").to_string() if g("NodeId") is not None else None,
            "event_id": g("EventId").hex() if g("EventId") else None,
            "type": g("EventType").to_string() if g("EventType") is not None else None,
            "active": g("ActiveState/Id"),
            "active_text": str(g("ActiveState").Text) if g("ActiveState") else None,
            "acked": g("AckedState/Id"),
            "retain": g("Retain"),
            "severity": g("Severity"),
            "source": g("SourceName"),
            "class": str(g("ConditionClassName").Text) if g("ConditionClassName") else None,
            "message": str(message.Text) if message else None,
        })

    async def until(self, pred, limit: float):
        end = time.monotonic() + limit
        while time.monotonic() < end:
            for e in self.seen:
                if pred(e):
                    return e
            await asyncio.sleep(0.05)
        return None


async def of_type_filter(c, fields, of):
    """The fields of event type `fields`, of events of type `of` and its
    subtypes (OfType: async-opcua never matches the InList of event types
    asyncua makes by default, docs/opcua.md)."""
    f = await get_filter_from_event_type([c.get_node(fields)], where_clause_generation=False)
    of_type = ua.ContentFilterElement()
    of_type.FilterOperator = ua.FilterOperator.OfType
    of_type.FilterOperands = [ua.LiteralOperand(Value=ua.Variant(of))]
    f.WhereClause = ua.ContentFilter()
    f.WhereClause.Elements = [of_type]
    return f


async def alarm_filter(c):
    """AlarmConditionType's fields, of events of ConditionType and its
    subtypes."""
    return await of_type_filter(
        c, ua.NodeId(ua.ObjectIds.AlarmConditionType), ua.NodeId(ua.ObjectIds.ConditionType)
    )


async def acknowledge(c, condition, comment):
    """Acknowledge on the condition's node, naming its event; the refusal's
    status name, or None."""
    node = c.get_node(ua.NodeId.from_string(condition["condition"]))
    try:
        await node.call_method(
            ACKNOWLEDGE,
            ua.Variant(bytes.fromhex(condition["event_id"]), ua.VariantType.ByteString),
            ua.LocalizedText(comment),
        )
        return None
    except ua.UaStatusCodeError as e:
        return type(e).__name__


async def conditions(url, creds: Path, work: Path):
    pw = users(creds)
    a, ns, falc = await as_operator(url, creds, work)
    mine = ConditionEvents()
    sub = await a.create_subscription(50, mine)
    await sub.subscribe_events(ua.ObjectIds.Server, evfilter=await alarm_filter(a), queuesize=100)
    say(step="listening")
    raised = await mine.until(lambda e: e["active"] is True and e["acked"] is False, 60)
    say(step="raised", condition=raised)
    if raised is None:
        return

    # A client that subscribes afterwards asks for what is retained.
    o = await connect(url, work, "observer", pw["observer"])
    late = ConditionEvents()
    late_sub = await o.create_subscription(50, late)
    await late_sub.subscribe_events(ua.ObjectIds.Server, evfilter=await alarm_filter(o), queuesize=100)
    await asyncio.sleep(0.5)
    before = len(late.seen)
    await o.get_node(ua.NodeId(ua.ObjectIds.ConditionType)).call_method(
        ua.NodeId(ua.ObjectIds.ConditionType_ConditionRefresh),
        ua.Variant(late_sub.subscription_id, ua.VariantType.UInt32),
    )
    same = lambda e: e["condition"] == raised["condition"]
    refreshed = await late.until(lambda e: same(e) and e["retain"] is True, 10)
    say(step="refreshed", before=before, condition=refreshed)
    say(step="observer_ack", refused=await acknowledge(o, raised, "an observer may not"))
    await o.disconnect()

    loop = asyncio.get_running_loop()
    await loop.run_in_executor(None, sys.stdin.readline)
    refused = await acknowledge(a, raised, "seen by the MES")
    acked = await mine.until(lambda e: same(e) and e["acked"] is True, 20)
    again = await acknowledge(a, acked or raised, "twice")
    say(step="acknowledged", refused=refused, condition=acked, again=again)

    await loop.run_in_executor(None, sys.stdin.readline)
    gone = await mine.until(lambda e: same(e) and e["retain"] is False, 20)
    say(step="released", condition=gone)

    changes, seen = await subscribe(a, ns, falc)
    await run_order(falc, ns, changes, seen)
    await a.disconnect()


MACHINERY = "http://opcfoundation.org/UA/Machinery/"
DI = "http://opcfoundation.org/UA/DI/"


async def typed_child(node, type_id):
    """The child of `node` (any forward hierarchical reference) whose type
    definition is `type_id`."""
    for child in await node.get_children(refs=ua.ObjectIds.HierarchicalReferences):
        if (await child.read_type_definition()) == type_id:
            return child
    return None


async def machines(c):
    """Every machine in Machinery's Machines folder: its Identification and
    current states, found the standard way."""
    m = await c.get_namespace_index(MACHINERY)
    di = await c.get_namespace_index(DI)
    folder = await c.nodes.objects.get_child([f"{m}:Machines"])
    out = {}
    for machine in await folder.get_children(refs=ua.ObjectIds.Organizes):
        name = (await machine.read_browse_name()).Name
        ident = await machine.get_child([f"{di}:Identification"])
        ident_type = await ident.read_type_definition()
        fields = {}
        for prop in ["Manufacturer", "Model", "SerialNumber", "SoftwareRevision", "ProductInstanceUri"]:
            v = await (await ident.get_child([f"{di}:{prop}"])).read_value()
            fields[prop] = v.Text if isinstance(v, ua.LocalizedText) else v
        blocks = await machine.get_child([f"{m}:MachineryBuildingBlocks"])
        states = {}
        for what, type_number in [("item", 1002), ("mode", 1008)]:
            sm = await typed_child(blocks, ua.NodeId(type_number, m))
            current = await sm.get_child(["0:CurrentState"])
            state_id = await (await current.get_child(["0:Id"])).read_value()
            states[what] = {
                "browse": (await sm.read_browse_name()).to_string(),
                "state": (await current.read_value()).Text,
                "id": state_id.to_string(),
                "id_in_machinery": state_id.NamespaceIndex == m,
            }
        out[name] = {
            "identification_type": ident_type.to_string(),
            "identification_is_machinery_type": ident_type == ua.NodeId(1012, m),
            "identification": fields,
            "states": states,
        }
    return out


async def machinery(url, creds: Path, work: Path):
    pw = users(creds)
    await admit(url, creds, work)
    c = await connect(url, work, "observer", pw["observer"])
    loop = asyncio.get_running_loop()
    n = 0
    while True:
        say(step=f"machines-{n}", machines=await machines(c))
        n += 1
        line = await loop.run_in_executor(None, sys.stdin.readline)
        if not line:
            break
    await c.disconnect()


JOBS = "http://opcfoundation.org/UA/Machinery/Jobs/"
RESULT = "http://opcfoundation.org/UA/Machinery/Result/"
ISA95 = "http://opcfoundation.org/UA/ISA95-JOBCONTROL_V2/"


def plain(v):
    """An asyncua value as JSON-friendly data."""
    if isinstance(v, list):
        return [plain(x) for x in v]
    if isinstance(v, ua.LocalizedText):
        return v.Text
    if isinstance(v, ua.Variant):
        return plain(v.Value)
    if hasattr(v, "__dataclass_fields__"):
        return {k: plain(getattr(v, k)) for k in v.__dataclass_fields__}
    if isinstance(v, (str, int, float, bool)) or v is None:
        return v
    return str(v)


async def job_management(c, cell):
    """Machine `cell`'s JobOrderControl and JobOrderResults, found by browse
    names and type definitions in the standards' namespaces."""
    m = await c.get_namespace_index(MACHINERY)
    jobs = await c.get_namespace_index(JOBS)
    isa95 = await c.get_namespace_index(ISA95)
    folder = await c.nodes.objects.get_child([f"{m}:Machines"])
    machine = None
    for node in await folder.get_children(refs=ua.ObjectIds.Organizes):
        if (await node.read_browse_name()).Name == cell:
            machine = node
    management = await machine.get_child([f"{jobs}:JobManagement"])
    assert await management.read_type_definition() == ua.NodeId(1003, jobs)
    control = await management.get_child([f"{jobs}:JobOrderControl"])
    assert await control.read_type_definition() == ua.NodeId(1002, isa95)
    results = await management.get_child([f"{jobs}:JobOrderResults"])
    assert await results.read_type_definition() == ua.NodeId(1003, isa95)
    return control, results, isa95


class ResultEvents:
    """ResultReadyEvents, as they arrive."""

    def __init__(self):
        self.results = []

    def event_notification(self, event):
        self.results.append(plain(event.Result))


async def result_management(c, cell):
    """Machine `cell`'s ResultManagement, found by browse name and type."""
    m = await c.get_namespace_index(MACHINERY)
    r = await c.get_namespace_index(RESULT)
    folder = await c.nodes.objects.get_child([f"{m}:Machines"])
    for node in await folder.get_children(refs=ua.ObjectIds.Organizes):
        if (await node.read_browse_name()).Name == cell:
            management = await node.get_child([f"{r}:ResultManagement"])
            assert await management.read_type_definition() == ua.NodeId(1004, r)
            return management, r
    return None, r


def job_order(job, recipe, parameters):
    return ua.ISA95JobOrderDataType(
        JobOrderID=job,
        WorkMasterID=[ua.ISA95WorkMasterDataType(ID=recipe, Description=ua.LocalizedText("cell recipe"))],
        Priority=5,
        JobOrderParameters=[
            ua.ISA95ParameterDataType(ID=k, Value=ua.Variant(v)) for k, v in parameters
        ],
    )


async def call(node, isa95, method, *args):
    """A JobOrderControl method's status code name and ReturnStatus: the
    Call service itself, since a refused command is Uncertain with its
    ReturnStatus (OPC 10031-4 B.2), which asyncua's call_method raises."""
    request = ua.CallMethodRequest()
    request.ObjectId = node.nodeid
    request.MethodId = (await node.get_child(f"{isa95}:{method}")).nodeid
    request.InputArguments = [a if isinstance(a, ua.Variant) else ua.Variant(a) for a in args]
    result = (await node.session.call([request]))[0]
    out = [v.Value for v in result.OutputArguments or []]
    return result.StatusCode.name, out[-1] if out else None, out[:-1]


async def mes(url, creds: Path, work: Path, cell, job):
    pw = users(creds)
    await admit(url, creds, work)
    c = await connect(url, work, "console", pw["console"])
    await c.load_data_type_definitions()
    machine = (await machines(c))[cell]
    control, results, isa95 = await job_management(c, cell)
    job_list = await control.get_child([f"{isa95}:JobOrderList"])
    response_list = await results.get_child([f"{isa95}:JobOrderResponseList"])
    no_comment = ua.Variant([], ua.VariantType.LocalizedText)

    # The refusals first: a job order nobody can run.
    wrong = await call(control, isa95, "StoreAndStart",
                       job_order(job + "-x", "dikdroog", [("Colour", "red")]), no_comment)
    unknown = await call(control, isa95, "Start", job + "-nope", no_comment)
    o = await connect(url, work, "observer", pw["observer"])
    await o.load_data_type_definitions()
    ocontrol, _, _ = await job_management(o, cell)
    observer = await call(ocontrol, isa95, "StoreAndStart",
                          job_order(job + "-o", "dikdroog", []), no_comment)
    await o.disconnect()

    management, r = await result_management(c, cell)
    before = await call(management, r, "GetLatestResult", ua.Variant(0, ua.VariantType.Int32))
    events = ResultEvents()
    event_sub = await c.create_subscription(50, events)
    ready = ua.NodeId(1002, r)
    await event_sub.subscribe_events(c.nodes.server, evfilter=await of_type_filter(c, ready, ready))

    states = []
    changes = Changes()
    sub = await c.create_subscription(50, changes)
    await sub.subscribe_data_change([job_list], sampling_interval=0.0)
    stored = await call(control, isa95, "StoreAndStart",
                        job_order(job, "dikdroog", [("Count", ua.Variant(1, ua.VariantType.Int32)),
                                                    ("Cell", cell)]), no_comment)
    twice = await call(control, isa95, "Store", job_order(job, "dikdroog", []), no_comment)
    say(step="stored", machine=machine, stored=stored[:2], twice=twice[:2], wrong=wrong[:2],
        unknown=unknown[:2], observer=observer[:2])
    began = time.monotonic()
    while time.monotonic() - began < 240:
        try:
            ident, val, at = await asyncio.wait_for(changes.queue.get(), 1)
        except asyncio.TimeoutError:
            continue
        for entry in val or []:
            if entry.JobOrder.JobOrderID == job:
                state = entry.State[0].StateText.Text
                if not states or states[-1] != state:
                    states.append(state)
        if states and states[-1] in ("Ended", "Aborted"):
            break
    listed = [plain(e) for e in await job_list.read_value() if e.JobOrder.JobOrderID == job]
    code, status, (response,) = await call(results, isa95, "RequestJobResponseByJobOrderID", job)
    responses = [plain(x) for x in await response_list.read_value() if x.JobOrderID == job]
    latest_code, latest_error, (handle, latest) = await call(
        management, r, "GetLatestResult", ua.Variant(0, ua.VariantType.Int32))
    result_id = latest.ResultMetaData.ResultId if latest else None
    by_id = await call(management, r, "GetResultById", result_id or "", ua.Variant(0, ua.VariantType.Int32))
    unknown_result = await call(management, r, "GetResultById", "999999", ua.Variant(0, ua.VariantType.Int32))
    began = time.monotonic()
    while not events.results and time.monotonic() - began < 10:
        await asyncio.sleep(0.1)
    say(step="ended", states=states, listed=listed, response=plain(response),
        response_status=[code, status], responses=responses,
        before=before[:2], latest=[latest_code, latest_error], result=plain(latest),
        by_id=[by_id[0], by_id[1], plain(by_id[2][1]) if by_id[2] else None],
        unknown_result=unknown_result[:2], events=events.results)
    await c.disconnect()


async def job_states(url, creds: Path, work: Path, cell):
    pw = users(creds)
    await admit(url, creds, work)
    c = await connect(url, work, "console", pw["console"])
    await c.load_data_type_definitions()
    control, _, isa95 = await job_management(c, cell)
    job_list = await control.get_child([f"{isa95}:JobOrderList"])
    ns = await c.get_namespace_index(f"urn:falc:{cell}")
    falc = await c.nodes.objects.get_child([f"{ns}:FALC"])
    question = c.get_node(ua.NodeId("FALC.Question", ns))
    none = ua.Variant([], ua.VariantType.LocalizedText)

    async def listed():
        return {e.JobOrder.JobOrderID: e.State[0].StateText.Text for e in await job_list.read_value()}

    async def until(job, want, answer=False, limit=120):
        began = time.monotonic()
        while time.monotonic() - began < limit:
            now = await listed()
            if now.get(job) == want:
                return True
            if answer and await question.read_value():
                await falc.call_method(f"{ns}:Answer", "ja")
            await asyncio.sleep(0.1)
        return False

    async def command(method, job):
        return (await call(control, isa95, method, job, none))[:2]

    async def store(method, job):
        return (await call(control, isa95, method, job_order(job, "dikdroog", []), none))[:2]

    async def until_gone(job, limit=30):
        began = time.monotonic()
        while job in await listed() and time.monotonic() - began < limit:
            await asyncio.sleep(0.1)

    # The same JobOrderID twice at once: one is taken, the other refused.
    twins = sorted(await asyncio.gather(store("Store", "J-T"), store("Store", "J-T")))
    twin_cancelled = await command("Cancel", "J-T")
    await until_gone("J-T")
    stored = [await store("Store", "J-1"), await store("Store", "J-2")]
    await until("J-2", "NotAllowedToStart", limit=30)
    say(step="stored", calls=stored, listed=await listed(), twins=twins,
        twin_cancelled=twin_cancelled)
    cancelled = [await command("Cancel", "J-2"), await command("Start", "J-2")]
    await until_gone("J-2")
    say(step="cancelled", calls=cancelled, listed=await listed())
    started = await command("Start", "J-1")
    running = await until("J-1", "Running")
    paused = await command("Pause", "J-1")
    interrupted = await until("J-1", "Interrupted")
    say(step="paused", calls=[started, paused], running=running, interrupted=interrupted,
        pause_again=await command("Pause", "J-1"))
    # Held until the test has looked at the cell (a line on stdin).
    await asyncio.get_running_loop().run_in_executor(None, sys.stdin.readline)
    resumed = await command("Resume", "J-1")
    running_again = await until("J-1", "Running")
    aborted = await command("Abort", "J-1")
    ended_aborted = await until("J-1", "Aborted")
    say(step="aborted", calls=[resumed, aborted], running=running_again, aborted=ended_aborted,
        cancel_ended=await command("Cancel", "J-1"))
    again = await store("StoreAndStart", "J-3")
    ended = await until("J-3", "Ended", answer=True, limit=180)
    cleared = await command("Clear", "J-3")
    await until_gone("J-3")
    say(step="ended", calls=[again, cleared], ended=ended, listed=await listed())
    await c.disconnect()


# The address a connection is made from (None: the system's choice): the
# siege's attacker connects from a second loopback address.
SOURCE = contextvars.ContextVar("source", default=None)


def connect_from_source():
    create = asyncio.BaseEventLoop.create_connection

    async def from_source(self, factory, host=None, port=None, **kw):
        if SOURCE.get() is not None and "local_addr" not in kw:
            kw["local_addr"] = (SOURCE.get(), 0)
        return await create(self, factory, host, port, **kw)

    asyncio.BaseEventLoop.create_connection = from_source


async def siege(url, creds: Path, work: Path, attacker: str, n: int):
    connect_from_source()
    await admit(url, creds, work)
    right = users(creds)["opcua"]
    done = asyncio.Event()

    async def attack():
        SOURCE.set(attacker)
        refused, ms = {}, []
        began = time.monotonic()
        for _ in range(n):
            one = time.monotonic()
            try:
                c = await client(url, work, "opcua", "not-the-password")
                await c.connect()
                await c.disconnect()
                kind = "logged in"
            except Exception as e:
                kind = type(e).__name__
            refused[kind] = refused.get(kind, 0) + 1
            ms.append(round((time.monotonic() - one) * 1000))
        done.set()
        return refused, round(time.monotonic() - began, 1), ms

    async def operator():
        ms, failed = [], []
        while not done.is_set() or len(ms) + len(failed) < 5:
            began = time.monotonic()
            try:
                c = await client(url, work, "opcua", right)
                await c.connect()
                ms.append(round((time.monotonic() - began) * 1000))
                await c.disconnect()
            except Exception as e:
                failed.append(type(e).__name__)
            await asyncio.sleep(1.0)
        return ms, failed

    (refused, took, attacker_ms), (ms, failed) = await asyncio.gather(attack(), operator())
    say(step="siege", attacker=refused, seconds=took, attacker_ms=attacker_ms,
        operator_ms=ms, operator_failed=failed)


async def watch(url, creds: Path, work: Path, nodes):
    pw = users(creds)
    await admit(url, creds, work)
    c = await connect(url, work, "observer", pw["observer"])
    ns = await c.get_namespace_index("urn:falc:falc1")
    changes = Changes()
    sub = await c.create_subscription(20, changes)
    await sub.subscribe_data_change([c.get_node(ua.NodeId(i, ns)) for i in nodes])
    say(step="watching")
    loop = asyncio.get_running_loop()
    told = loop.run_in_executor(None, sys.stdin.readline)
    while not told.done():
        try:
            ident, val, at = await asyncio.wait_for(changes.queue.get(), 0.2)
        except asyncio.TimeoutError:
            continue
        say(step="change", node=ident, value=str(val), at=at)
    await c.disconnect()


def main():
    what, url, creds, work = sys.argv[1:5]
    creds, work = Path(creds), Path(work)
    work.mkdir(parents=True, exist_ok=True)
    if what == "scenario":
        asyncio.run(scenario(url, creds, work))
    elif what == "order":
        asyncio.run(order(url, creds, work))
    elif what == "user-cert":
        asyncio.run(user_cert(work))
    elif what == "by-certificate":
        asyncio.run(by_certificate(url, creds, work))
    elif what == "throttle":
        asyncio.run(throttle(url, creds, work, float(sys.argv[5])))
    elif what == "plant":
        asyncio.run(plant(url, creds, work, *sys.argv[5:8]))
    elif what == "conditions":
        asyncio.run(conditions(url, creds, work))
    elif what == "machinery":
        asyncio.run(machinery(url, creds, work))
    elif what == "mes":
        asyncio.run(mes(url, creds, work, sys.argv[5], sys.argv[6]))
    elif what == "job-states":
        asyncio.run(job_states(url, creds, work, sys.argv[5]))
    elif what == "siege":
        asyncio.run(siege(url, creds, work, sys.argv[5], int(sys.argv[6])))
    elif what == "watch":
        asyncio.run(watch(url, creds, work, sys.argv[5:]))
    else:
        sys.exit(f"unknown command {what}")


if __name__ == "__main__":
    main()
