//! The set of fields marked for posting at the end of a processing (the record's MMAP/NMAP).

use zmotor_msgs::Field;

const WORDS: usize = Field::COUNT.div_ceil(64);

#[derive(Clone, Debug, Default)]
pub(super) struct Marks([u64; WORDS]);

impl Marks {
    pub(super) fn insert(&mut self, field: Field) {
        let i = field as usize;
        self.0[i / 64] |= 1 << (i % 64);
    }

    pub(super) fn clear(&mut self, field: Field) {
        let i = field as usize;
        self.0[i / 64] &= !(1 << (i % 64));
    }

    pub(super) fn contains(&self, field: Field) -> bool {
        let i = field as usize;
        self.0[i / 64] & (1 << (i % 64)) != 0
    }

    /// The marked fields in catalogue order; the set is left empty.
    pub(super) fn take(&mut self) -> Vec<Field> {
        let marked: Vec<Field> = Field::all().filter(|f| self.contains(*f)).collect();
        self.0 = [0; WORDS];
        marked
    }
}
