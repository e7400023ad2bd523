//! `billboards.bin` of any version, alone and as a delta on a real keyframe: the
//! decoder answers an error or a keyframe, never a panic, a hang or an allocation the
//! bytes' own size does not justify.
#![no_main]

use std::sync::OnceLock;

use cloudscape_core::products::billboards::{BinBillboards, decode_bin, decode_bin_after};
use libfuzzer_sys::fuzz_target;

/// The keyframe a delta seed follows (fuzz/seeds/billboards/previous.bin).
fn previous() -> &'static BinBillboards {
    static PREVIOUS: OnceLock<BinBillboards> = OnceLock::new();
    PREVIOUS.get_or_init(|| {
        decode_bin(include_bytes!("../seeds/billboards/previous.bin")).expect("the seed keyframe decodes")
    })
}

fuzz_target!(|data: &[u8]| {
    for decoded in [decode_bin(data), decode_bin_after(data, Some(previous()))].into_iter().flatten() {
        // What decodes is whole: every record has both ends, within the sheet.
        for r in &decoded.records {
            for e in &r.ends {
                assert!(e.splat_tau.is_none_or(|t| t >= 0.0));
                assert!(decoded.version < 3 || e.splat < decoded.splat_count.max(1));
            }
        }
    }
});
