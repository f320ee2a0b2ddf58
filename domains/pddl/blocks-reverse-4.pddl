; Reverse a tower of four: a on b on c on d becomes d on c on b on a.
; Optimal cost 8: every block must be picked up and put down once.
(define (problem blocks-reverse-4)
  (:domain blocks)
  (:objects a b c d - block)
  (:init (handempty) (on a b) (on b c) (on c d) (ontable d) (clear a))
  (:goal (and (on d c) (on c b) (on b a) (ontable a))))
