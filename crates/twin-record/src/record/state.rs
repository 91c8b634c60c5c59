//! The recorder's part of a snapshot (docs/snapshots.md): what a recording started from a
//! snapshot needs to go on as the original did, so that from the snapshot's point on it
//! writes the original's messages byte for byte, with the same channel ids and sequence
//! numbers.
//!
//! Saved: the channels in the order they were registered (their ids follow from that
//! order: a resumed recording registers them again first), each one's next sequence
//! number and thinning instant; the messages held for log-time order; the latest log time
//! written; the CAN frame trains being gathered; the PC sessions' open runs. Not saved,
//! because they are rebuilt from the configuration or are caches: the channel rules (the
//! saved text is compared instead), the schema ids (written with the channels, in the same
//! order), the encoder's rule lookups, its rotation cache and reused buffers. Message
//! counts start again at zero: they count what the resumed file holds.

use super::{
    CHANNEL_KINDS, ChannelKind, EventEncoder, McapOut, PcRunTally, Recorder, SimTime, Train,
    set_str,
};
use anyhow::{Context as _, bail};

/// One registered channel.
struct SavedChan {
    /// Its kind, as an index of [`CHANNEL_KINDS`].
    kind: u32,
    key: String,
    id: u16,
    seq: u32,
    last_kept: Option<u64>,
}
snap::fields!(SavedChan {
    kind,
    key,
    id,
    seq,
    last_kept
});

/// A CAN frame train being gathered.
struct SavedTrain {
    t0_ns: u64,
    from: String,
    can_id: Vec<u32>,
    dlc: Vec<u8>,
    end_ns: Vec<u32>,
    dropped: Vec<u32>,
    data: Vec<u8>,
}
snap::fields!(SavedTrain {
    t0_ns,
    from,
    can_id,
    dlc,
    end_ns,
    dropped,
    data
});

/// The recorder's state.
struct Saved {
    /// The channel rules, as `[record] channels` writes them.
    rules: String,
    chans: Vec<SavedChan>,
    /// The held messages in order: channel index, log time, bytes.
    held: Vec<(usize, u64, Vec<u8>)>,
    written_max: u64,
    /// Each bus's open train, in the order the buses appeared.
    trains: Vec<(String, Option<SavedTrain>)>,
    /// Each PC session's open run: id, ACTIVE since (ns), bytes downlinked.
    pc_runs: Vec<(u8, Option<u64>, u64)>,
}
snap::fields!(Saved {
    rules,
    chans,
    held,
    written_max,
    trains,
    pc_runs
});

fn kind_index(kind: ChannelKind) -> u32 {
    CHANNEL_KINDS.iter().position(|k| *k == kind).unwrap_or(0) as u32
}

impl Recorder {
    /// The recorder's state, for a snapshot: taken between two events, it is the state
    /// after every event written so far.
    pub fn save_state(&self) -> Vec<u8> {
        let McapOut {
            chans,
            order,
            written_max,
            rules,
            ..
        } = &self.out;
        let saved = Saved {
            rules: twin_scenario::channels::format_rules(rules),
            chans: chans
                .iter()
                .map(|c| SavedChan {
                    kind: kind_index(c.kind),
                    key: c.key.clone(),
                    id: c.id,
                    seq: c.seq,
                    last_kept: c.last_kept,
                })
                .collect(),
            held: order.held().map(|(c, t, d)| (c, t, d.to_vec())).collect(),
            written_max: *written_max,
            trains: self.enc.saved_trains(),
            pc_runs: self
                .enc
                .pc_runs
                .iter()
                .map(|(id, r)| (*id, r.started.map(SimTime::as_ns), r.downlinked_bytes))
                .collect(),
        };
        snap::to_bytes(&saved)
    }

    /// Go on from a snapshot's recorder state `state` (taken by [`Recorder::save_state`] of
    /// the same scenario's recording): registers the saved channels in their order (the
    /// same ids), and takes back the held messages, the sequence numbers and the open
    /// trains. Call it right after [`Recorder::create`]. The recording says where it
    /// starts (metadata `m6p-twin-resumed`: `at_ns`, the snapshot's instant) and carries
    /// the snapshot `snapshot_file` as an attachment, so that `replay` can start there.
    pub fn resume(
        &mut self,
        state: &[u8],
        at: SimTime,
        snapshot_file: &[u8],
    ) -> anyhow::Result<()> {
        let mut r = snap::Reader::new(state);
        let saved = <Saved as snap::SnapNew>::read(&mut r)
            .and_then(|s| r.finish().map(|()| s))
            .context("reading the snapshot's recorder state")?;
        let rules = twin_scenario::channels::format_rules(&self.out.rules);
        if saved.rules != rules {
            bail!(
                "the snapshot's recording kept channels `{}`, this one `{rules}`: a recording \
                 goes on only with the same channels",
                saved.rules
            );
        }
        self.write_resumed(at, snapshot_file)?;
        self.out.take_channels(&saved.chans)?;
        for (chan, log_time, data) in &saved.held {
            if *chan >= self.out.chans.len() {
                bail!(
                    "the snapshot's recorder state holds a message of channel {chan}, which it does not have"
                );
            }
            self.out.order.hold(*chan, *log_time, data);
        }
        self.out.written_max = saved.written_max;
        self.enc.take_trains(saved.trains);
        self.enc.pc_runs = saved
            .pc_runs
            .into_iter()
            .map(|(id, started, downlinked_bytes)| {
                let started = started.map(SimTime::from_ns);
                (
                    id,
                    PcRunTally {
                        started,
                        downlinked_bytes,
                    },
                )
            })
            .collect();
        // The per-bus leave-out flags follow the trains' order.
        self.enc.set_rules(self.out.rules.clone());
        Ok(())
    }

    /// The metadata and attachment of a resumed recording.
    fn write_resumed(&mut self, at: SimTime, snapshot_file: &[u8]) -> anyhow::Result<()> {
        let ctx = || format!("writing recording {}", self.out.path.display());
        let metadata = [
            ("at_ns".to_owned(), at.as_ns().to_string()),
            (
                "snapshot_attachment".to_owned(),
                super::SNAPSHOT_ATTACHMENT.to_owned(),
            ),
        ]
        .into_iter()
        .collect();
        self.out
            .writer
            .metadata(super::RESUMED_METADATA_NAME, &metadata)
            .with_context(ctx)?;
        self.attach_snapshot(at, snapshot_file)
    }

    /// Carry the snapshot file taken at `at` (an attachment named
    /// [`super::SNAPSHOT_ATTACHMENT`] logged at its instant).
    pub fn attach_snapshot(&mut self, at: SimTime, snapshot_file: &[u8]) -> anyhow::Result<()> {
        let ctx = || format!("writing recording {}", self.out.path.display());
        let log_time = self.enc.base_ns().saturating_add(at.as_ns());
        self.out
            .writer
            .attach(
                log_time,
                log_time,
                super::SNAPSHOT_ATTACHMENT,
                "application/octet-stream",
                snapshot_file,
            )
            .with_context(ctx)
    }
}

impl McapOut {
    /// Register the saved channels after those registered already (the fixed ones, which
    /// must be the saved list's first), checking that each gets its saved id.
    fn take_channels(&mut self, saved: &[SavedChan]) -> anyhow::Result<()> {
        for (i, s) in saved.iter().enumerate() {
            let Some(&kind) = CHANNEL_KINDS.get(s.kind as usize) else {
                bail!(
                    "the snapshot's recorder state names channel kind {}, which this build does not have",
                    s.kind
                );
            };
            let i = match self.chans.get(i) {
                Some(c) if c.kind == kind && c.key == s.key => i,
                Some(c) => bail!(
                    "the snapshot's recording registered {} as channel {i}, this one {}",
                    kind.topic(&s.key),
                    c.topic
                ),
                None => self.add_channel(kind, &s.key)?,
            };
            let c = &mut self.chans[i];
            if c.id != s.id {
                bail!(
                    "channel {} would have id {}, the snapshot's recording gave it {}",
                    c.topic,
                    c.id,
                    s.id
                );
            }
            c.seq = s.seq;
            c.last_kept = s.last_kept;
        }
        Ok(())
    }
}

impl EventEncoder {
    fn saved_trains(&self) -> Vec<(String, Option<SavedTrain>)> {
        self.trains
            .iter()
            .map(|(bus, train)| {
                let train = train.as_ref().map(|t| SavedTrain {
                    t0_ns: t.t0.as_ns(),
                    from: t.msg.from.clone(),
                    can_id: t.msg.can_id.to_vec(),
                    dlc: t.msg.dlc.to_vec(),
                    end_ns: t.msg.end_ns.to_vec(),
                    dropped: t.msg.dropped.to_vec(),
                    data: t.data.clone(),
                });
                (bus.to_string(), train)
            })
            .collect()
    }

    fn take_trains(&mut self, saved: Vec<(String, Option<SavedTrain>)>) {
        self.trains = saved
            .into_iter()
            .map(|(bus, train)| {
                let train = train.map(|s| {
                    let mut t = Train {
                        t0: SimTime::from_ns(s.t0_ns),
                        data: s.data,
                        from: Some(s.from.as_str().into()),
                        ..Train::default()
                    };
                    t.msg.t_ns = s.t0_ns;
                    set_str(&mut t.msg.from, &s.from);
                    t.msg.can_id.extend(s.can_id);
                    t.msg.dlc.extend(s.dlc);
                    t.msg.end_ns.extend(s.end_ns);
                    t.msg.dropped.extend(s.dropped);
                    t
                });
                (bus.into(), train)
            })
            .collect();
    }
}
