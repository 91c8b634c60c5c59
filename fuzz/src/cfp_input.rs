//! The `cfp_reassembly` target's input: a reassembler configuration, a stream of CAN
//! frames with the time before each, timeouts, and one packet for the fragmenter round trip.

fuzz_enum! {
    /// One step of the reassembler's input.
    pub enum CfpOp {
        /// A frame `dt_us` microseconds after the previous step (id masked to 29 bits,
        /// `dlc % 9` bytes of `data`).
        Frame { id: u32, dlc: u8, data: [u8; 8], dt_us: u32 },
        /// `dt_ms` milliseconds pass; stale partial packets are purged when due.
        Wait { dt_ms: u32 },
    }
}

fuzz_struct! {
    /// The whole input.
    pub struct CfpInput {
        /// Slots `1 + config % 12`; bit 7: MTU 2042 (CFP's largest) instead of 256.
        pub config: u8,
        /// The round-trip packet's header word.
        pub word: u32,
        /// Its data (cut at 2042 bytes).
        pub data: Vec<u8>,
        /// The next-hop MAC of its frames.
        pub mac: u8,
        /// The fragmenter's first ident.
        pub ident: u16,
        /// The frames and waits.
        pub ops: Vec<CfpOp>,
    }
}
