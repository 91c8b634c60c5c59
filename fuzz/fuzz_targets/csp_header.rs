//! `csp_header`: the CSP 1.x header and packet parsers (`csp::Header::parse`,
//! `csp::Packet::parse`) on arbitrary bytes, and the ICD request-reply framing
//! (`csp::reqrep::{Request, Reply}::parse`) on the packet data.
//!
//! Asserts:
//! - the header parses exactly when there are at least 4 bytes (every 32-bit word is a
//!   header), validates, and writes back the same 4 bytes (`to_bytes`, `emit`, the word);
//! - a parsed packet writes back the input byte for byte and parses again to the same packet;
//! - the reply of the reply is the original header (`Header::reply`);
//! - request and reply framing parse exactly when long enough and write back the same bytes.
#![no_main]

use csp::reqrep::{Reply, Request};
use csp::{Header, Packet};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    match Header::parse(data) {
        Ok(h) => {
            assert!(data.len() >= 4);
            assert_eq!(h.to_bytes(), data[..4]);
            assert!(h.validate().is_ok(), "{h}");
            assert_eq!(Header::from_word(h.to_word()), h);
            let mut b = [0u8; 4];
            assert!(h.emit(&mut b).is_ok());
            assert_eq!(b, h.to_bytes());
            assert_eq!(h.reply(h.dst).reply(h.src), h);
            let _ = h.to_string();
        }
        Err(_) => assert!(data.len() < 4),
    }

    if let Ok(p) = Packet::parse(data) {
        let bytes = p.to_bytes();
        assert_eq!(bytes, data);
        assert_eq!(Packet::parse(&bytes).ok(), Some(p.clone()));

        match Request::parse(&p.data) {
            Ok(r) => assert_eq!(r.to_vec(), p.data),
            Err(_) => assert!(p.data.is_empty()),
        }
        match Reply::parse(&p.data) {
            Ok(r) => assert_eq!(r.to_vec(), p.data),
            Err(_) => assert!(p.data.len() < 2),
        }
    }
});
