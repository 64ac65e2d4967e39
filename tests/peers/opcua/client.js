// node-opcua as a peer client of our OPC UA server (tests/test_opcua_peer.py).
// Prints one JSON object per line on stdout:
//   {"step":"connected"} {"step":"browse",...} {"step":"read",...} {"step":"ready"}
//   {"step":"event",...} ... and {"step":"error","message":...} on failure.
// Arguments (JSON in argv[2]): url, unit, certificateFile, privateKeyFile, applicationUri,
//   user, password, pkiDir, waitEvents (number of alarm events to wait for), timeoutMs,
//   ackByMethod (call the unit's own Acknowledge method after the first event),
//   ackStandard (acknowledge the first event's condition with Part 9's Acknowledge,
//   i=9111, naming its EventId), refresh (call ConditionRefresh once subscribed),
//   anonymous (log in without a user).
"use strict";
const {
  OPCUAClient, MessageSecurityMode, SecurityPolicy, AttributeIds, UserTokenType,
  OPCUACertificateManager, constructEventFilter, TimestampsToReturn, callConditionRefresh,
} = require("node-opcua");

const out = (o) => process.stdout.write(JSON.stringify(o) + "\n");

async function main() {
  const a = JSON.parse(process.argv[2]);
  const certificateManager = new OPCUACertificateManager({
    rootFolder: a.pkiDir, automaticallyAcceptUnknownCertificate: true,
  });
  await certificateManager.initialize();
  const client = OPCUAClient.create({
    applicationName: "node-opcua peer",
    applicationUri: a.applicationUri,
    securityMode: MessageSecurityMode.SignAndEncrypt,
    securityPolicy: SecurityPolicy.Basic256Sha256,
    certificateFile: a.certificateFile,
    privateKeyFile: a.privateKeyFile,
    clientCertificateManager: certificateManager,
    endpointMustExist: false,
    connectionStrategy: { maxRetry: 0, initialDelay: 100, maxDelay: 200 },
    requestedSessionTimeout: 30000,
  });
  const timer = setTimeout(() => { out({ step: "error", message: "timeout" }); process.exit(3); },
    a.timeoutMs || 30000);
  try {
    await client.connect(a.url);
    const session = await client.createSession(a.anonymous
      ? { type: UserTokenType.Anonymous }
      : { type: UserTokenType.UserName, userName: a.user, password: a.password });
    out({ step: "connected", securityMode: MessageSecurityMode[client.securityMode] });
    const ns = (await session.readNamespaceArray()).indexOf("urn:diag-plugin:diagnosis");
    const units = await session.browse(`ns=${ns};s=Units`);
    out({ step: "browse", units: units.references.map((r) => r.browseName.name) });
    const unitRefs = await session.browse(`ns=${ns};s=Units.${a.unit}`);
    const names = unitRefs.references.map((r) => r.browseName.name);
    const vars = ["DeviceHealth", "StatusName", "Quality", `Certainty.${a.cert || "f_S"}`];
    const dvs = await session.read(vars.map((v) => ({
      nodeId: `ns=${ns};s=Units.${a.unit}.${v}`, attributeId: AttributeIds.Value,
    })));
    const read = {};
    vars.forEach((v, i) => {
      read[v] = { value: dvs[i].value.value, status: dvs[i].statusCode.name };
    });
    out({ step: "read", children: names, values: read });

    const sub = await session.createSubscription2({
      requestedPublishingInterval: 100, requestedMaxKeepAliveCount: 20,
      requestedLifetimeCount: 100, publishingEnabled: true, priority: 1,
    });
    const fields = ["EventType", "SourceName", "SourceNode", "Message", "Severity", "Retain",
      "ActiveState", "ActiveState.Id", "AckedState", "AckedState.Id", "ConditionName",
      "EventId", "ConditionId", "ConfirmedState.Id", "Comment", "ClientUserId"];
    const item = await sub.monitor(
      { nodeId: "i=2253", attributeId: AttributeIds.EventNotifier },
      { queueSize: 100, filter: constructEventFilter(fields), discardOldest: true },
      TimestampsToReturn.Neither,
    );
    let seen = 0;
    let acked = false;
    const done = new Promise((resolve) => {
      item.on("changed", (values) => {
        const ev = {};
        fields.forEach((f, i) => {
          const v = values[i].value;
          ev[f] = v && typeof v === "object" && "text" in v ? v.text : (v && v.toString ? v.toString() : v);
          if (typeof v === "number" || typeof v === "boolean") ev[f] = v;
          if (Buffer.isBuffer(v)) ev[f] = v.toString("hex");
        });
        out({ step: "event", event: ev });
        const isAlarm = ev.EventType === "ns=0;i=2915";
        if (isAlarm && a.ackStandard && !acked) {
          acked = true;
          session.acknowledgeCondition(values[fields.indexOf("ConditionId")].value,
            values[fields.indexOf("EventId")].value, "seen by the peer")
            .then((status) => out({ step: "ackStandard", status: status.name }))
            .catch((err) => out({ step: "ackStandard", status: String(err.message || err) }));
        }
        if (!isAlarm) return; // RefreshStart/End events are not counted
        seen += 1;
        if (seen === 1 && a.ackByMethod) {
          session.call({
            objectId: `ns=${ns};s=Units.${a.unit}`,
            methodId: `ns=${ns};s=Units.${a.unit}.Acknowledge`, inputArguments: [],
          }).then((r) => out({
            step: "acknowledge", status: r.statusCode.name,
            changed: r.outputArguments.length ? r.outputArguments[0].value : null,
          }));
        }
        if (seen >= (a.waitEvents || 1)) resolve();
      });
    });
    if (a.refresh) {
      const status = await callConditionRefresh(session, sub.subscriptionId);
      out({ step: "refresh", status: status.name });
    }
    out({ step: "ready" });
    await done;
    await sub.terminate();
    await session.close();
    await client.disconnect();
    clearTimeout(timer);
    out({ step: "done" });
    process.exit(0);
  } catch (err) {
    clearTimeout(timer);
    out({ step: "error", message: String(err && err.message ? err.message : err) });
    try { await client.disconnect(); } catch (e) { /* already gone */ }
    process.exit(2);
  }
}

main();
