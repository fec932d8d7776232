//! The JSON schemas of a recording's channels (`jsonschema` encoding), so
//! that Foxglove and other tools know every field to plot.

/// The recording's topics, in the order their channels are written.
pub const TOPICS: [&str; 6] = [
    "/ndr/command",
    "/ndr/state",
    "/ndr/event",
    "/ndr/stats",
    "/ndr/network",
    "/ndr/probe",
];

/// Each topic's schema name and schema.
pub(super) fn schemas() -> [(&'static str, String); 6] {
    [
        ("ndr.Release", release("a command released by the remote")),
        ("ndr.Release", release("a state released by the base")),
        ("ndr.Event", EVENT.to_owned()),
        ("ndr.Stats", stats()),
        ("ndr.Arrival", ARRIVAL.to_owned()),
        ("ndr.Probe", PROBE.to_owned()),
    ]
}

fn release(what: &str) -> String {
    format!(
        r#"{{"$schema":"https://json-schema.org/draft/2020-12/schema","title":"ndr.Release","description":"One release of {what}: log time the release, publish time the original send","type":"object","properties":{{
"link":{{"type":"integer","description":"the link's number in the recording"}},
"seq":{{"type":"integer","description":"the sample's sequence number"}},
"status":{{"type":"string","enum":["fresh","repeated","late"],"description":"fresh; repeated (the due sample missing, the last one again); late (never released: lost, or came after its release time)"}},
"sent_ns":{{"type":"integer","description":"send time, ns on the sender's clock"}},
"arrived_ns":{{"type":["integer","null"],"description":"arrival, ns on this side's clock"}},
"released_ns":{{"type":"integer","description":"release, ns on this side's clock"}},
"end_to_end_s":{{"type":"number","description":"release - send, s (the two clocks as they are)"}},
"added_delay_s":{{"type":["number","null"],"description":"release - arrival, s"}},
"grtt_s":{{"type":["number","null"],"description":"the round trip this release closed, s"}},
"answers_sent_ns":{{"type":["integer","null"],"description":"send time on this side's clock of this side's sample the round trip started from"}},
"nrtt_s":{{"type":["number","null"],"description":"the network round trip this side measured last, s"}},
"values":{{"type":"object","additionalProperties":{{"type":"number"}},"description":"the values by channel name"}}
}},"required":["link","seq","status","sent_ns","released_ns","values"]}}"#
    )
}

const EVENT: &str = r#"{"$schema":"https://json-schema.org/draft/2020-12/schema","title":"ndr.Event","description":"A link event","type":"object","properties":{
"link":{"type":"integer"},
"side":{"type":"string","enum":["base","remote"]},
"kind":{"type":"string","enum":["attached","connected","started","paused","link_lost","delay_changed","round_trip_changed","link_restored","closed"]},
"at_ns":{"type":"integer","description":"ns on this side's clock"},
"period_s":{"type":"number"},
"ns":{"type":"integer","description":"the regulators' nominal size"},
"delay_s":{"type":"number","description":"delay_changed: the new end-to-end delay"},
"grtt_s":{"type":"number","description":"round_trip_changed: the GRTT that showed the change"},
"ticks":{"type":"integer"},
"silent_for_s":{"type":"number","description":"link_lost: time since the last fresh sample"},
"outage_s":{"type":"number","description":"link_restored: how long the outage lasted"},
"error":{"type":"string","description":"closed: why"}
},"required":["link","side","kind","at_ns"]}"#;

const ARRIVAL: &str = r#"{"$schema":"https://json-schema.org/draft/2020-12/schema","title":"ndr.Arrival","description":"A sample's arrival (log time) and its send (publish time), or a sample that never came in time","type":"object","properties":{
"link":{"type":"integer"},
"direction":{"type":"string","enum":["fwd","bwd"],"description":"fwd: base to remote; bwd: remote to base"},
"seq":{"type":"integer"},
"sent_ns":{"type":"integer","description":"ns on the sender's clock"},
"arrived_ns":{"type":["integer","null"],"description":"ns on this side's clock"},
"raw_s":{"type":["number","null"],"description":"arrival - send, the two clocks as they are"},
"one_way_s":{"type":["number","null"],"description":"the one-way delay: raw_s - clock_offset_s"},
"clock_offset_s":{"type":"number","description":"the clock offset estimate, this side - sender"},
"missing":{"type":"boolean","description":"never released: lost, or came after its release time"}
},"required":["link","direction","seq","sent_ns","missing"]}"#;

const PROBE: &str = r#"{"$schema":"https://json-schema.org/draft/2020-12/schema","title":"ndr.Probe","description":"A probe's arrival (log time) and its send (publish time): the initialization pattern's frames, whose round trips size the queue","type":"object","properties":{
"link":{"type":"integer"},
"direction":{"type":"string","enum":["fwd","bwd"],"description":"fwd: base to remote; bwd: remote to base"},
"seq":{"type":"integer","description":"the probe's sequence number (probes and samples share the count)"},
"sent_ns":{"type":"integer","description":"ns on the sender's clock"},
"arrived_ns":{"type":"integer","description":"ns on this side's clock"},
"raw_s":{"type":"number","description":"arrival - send, the two clocks as they are"},
"one_way_s":{"type":"number","description":"the one-way delay: raw_s - clock_offset_s"},
"clock_offset_s":{"type":"number","description":"the clock offset estimate, this side - sender"}
},"required":["link","direction","seq","sent_ns","arrived_ns","one_way_s"]}"#;

fn stats() -> String {
    const FIELDS: [(&str, &str); 32] = [
        ("link", "integer"),
        ("side", "string"),
        ("phase", "string"),
        ("period_s", "number"),
        ("ns", "integer"),
        ("queue_len", "integer"),
        ("samples_sent", "integer"),
        ("samples_received", "integer"),
        ("released_fresh", "integer"),
        ("released_held", "integer"),
        ("underflows", "integer"),
        ("late", "integer"),
        ("samples_lost", "integer"),
        ("samples_recovered", "integer"),
        ("link_lost", "integer"),
        ("nrtt_mean_s", "number"),
        ("nrtt_std_s", "number"),
        ("nrtt_last_s", "number"),
        ("grtt_mean_s", "number"),
        ("grtt_std_s", "number"),
        ("grtt_count", "integer"),
        ("one_way_rx_mean_s", "number"),
        ("clock_offset_s", "number"),
        ("clock_skew_ppm", "number"),
        ("playout_delay_s", "number"),
        ("delay_changes", "integer"),
        ("release_lateness_p50_s", "number"),
        ("release_lateness_p99_s", "number"),
        ("release_lateness_max_s", "number"),
        ("app_dropped", "integer"),
        ("record_queued", "integer"),
        ("record_dropped", "integer"),
    ];
    let props: Vec<String> = FIELDS
        .iter()
        .map(|(name, ty)| {
            if *name == "nrtt_last_s" {
                format!(r#""{name}":{{"type":["{ty}","null"]}}"#)
            } else {
                format!(r#""{name}":{{"type":"{ty}"}}"#)
            }
        })
        .collect();
    format!(
        r#"{{"$schema":"https://json-schema.org/draft/2020-12/schema","title":"ndr.Stats","description":"A link's counters, once a second","type":"object","properties":{{{}}}}}"#,
        props.join(",")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_schema_is_json_with_the_fields_of_its_messages() {
        for (name, schema) in schemas() {
            let v: serde_json::Value = serde_json::from_str(&schema).expect(name);
            assert_eq!(v["type"], "object", "{name}");
            assert!(v["properties"].as_object().is_some_and(|p| !p.is_empty()));
        }
    }
}
