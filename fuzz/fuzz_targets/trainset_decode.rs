//! The training-set (`.isat`) decoder on arbitrary bytes, raw and with the checksum fixed up
//! (so the entry parser, the NPY reader and validation are reached).
#![no_main]

use isa_core::model_io::fnv1a64;
use isa_core::trainset_io;
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = trainset_io::decode(data, "fuzz");
    if data.len() >= 8 {
        let mut b = data[..data.len() - 8].to_vec();
        let sum = fnv1a64(&b);
        b.extend_from_slice(&sum.to_le_bytes());
        if let Ok(ts) = trainset_io::decode(&b, "fuzz") {
            // What decodes re-encodes to a file that decodes the same.
            let again = trainset_io::decode(&trainset_io::encode(&ts), "again").unwrap();
            assert_eq!(again.parts, ts.parts);
        }
    }
});
