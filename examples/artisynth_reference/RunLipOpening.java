// Headless run of ArtiSynth's own BadinFaceDemoLipOpening (artisynth_models), for wface's comparison.
//
// Builds the demo exactly as its build() does (the ten OOP rings, BlemkerMuscle at 1e5 Pa, lip-lip and
// lip-skull contact, gravity, ConstrainedBackwardEuler at 5 ms), plays the OOP excitation from an
// ArtiSynth probe data file (the demo's data/approximant/oop.txt: CubicStep, 0.3 at 0.8 s) through a
// NumericInputProbe, as the demo's attach() does, and writes the face's FEM node positions every
// 0.01 s. No viewer: the demo's own area measure counts green pixels on screen, so wface measures the
// aperture from the dumped nodes instead (examples/artisynth_lip_area.py).
//
// Usage (classpath: artisynth_core's classes and jars, artisynth_models' classes; java.library.path:
// the core's native libraries, PardisoJNI, TetgenJNI and RobustPreds):
//   javac -cp $CP RunLipOpening.java
//   java -Djava.awt.headless=true -Djava.library.path=$NATIVE -cp .:$CP RunLipOpening NODES.txt 1.0 OOP.txt
// Options (system properties):
//   -Dlip.contact=all|lips|skull|none   collisions as the demo sets them (all), lip-lip only,
//                                 face-bone only, or none
//   -Dlip.pentol=METRES           MechModel penetration tolerance (default: ArtiSynth's)
//   -Dlip.gravity=false           no gravity
//   -Dlip.contacts=FILE           also write the contacts at every dump: per frame a line "T <time s> <count>",
//                                 then per contact "x0 y0 z0 x1 y1 z1 nx ny nz force_N pair" (the two contact
//                                 points, the normal and the force, Badin frame; pair: lips, jaw or maxilla)
// Output: per frame a line "T <time s> <OOP excitation>" and then one line "x y z" (metres, Badin frame)
// per face node, in the node file's order.
import java.io.BufferedWriter;
import java.io.FileWriter;
import java.io.PrintWriter;

import artisynth.core.femmodels.FemModel3d;
import artisynth.core.femmodels.FemMuscleModel;
import artisynth.core.femmodels.FemNode3d;
import artisynth.core.femmodels.MuscleBundle;
import artisynth.core.mechmodels.CollisionBehavior;
import artisynth.core.mechmodels.CollisionResponse;
import artisynth.core.mechmodels.ContactData;
import artisynth.core.mechmodels.MechModel;
import artisynth.core.mechmodels.RigidBody;
import artisynth.core.probes.NumericInputProbe;
import artisynth.core.util.TimeBase;
import artisynth.models.face.BadinFaceDemoLipOpening;

public class RunLipOpening {
   static final double DUMP_INTERVAL_S = 0.01;

   public static void main (String[] args) throws Exception {
      if (args.length != 3) {
         System.err.println ("usage: RunLipOpening NODES_OUT.txt END_TIME_S OOP_PROBE.txt");
         System.exit (2);
      }
      double tEnd = Double.parseDouble (args[1]);
      BadinFaceDemoLipOpening demo = new BadinFaceDemoLipOpening ();
      demo.build (new String[0]);
      MechModel mech = (MechModel)demo.models ().get ("mech");
      FemMuscleModel face = (FemMuscleModel)mech.models ().get ("badinface");
      MuscleBundle oop = face.getMuscleBundles ().get ("OOP");
      RigidBody jaw = mech.rigidBodies ().get ("badinjaw");
      RigidBody maxilla = mech.rigidBodies ().get ("badinmaxilla");

      String contact = System.getProperty ("lip.contact", "all");
      if (!java.util.Arrays.asList ("all", "lips", "skull", "none").contains (contact)) {
         throw new IllegalArgumentException ("lip.contact must be all, lips, skull or none, got " + contact);
      }
      if (contact.equals ("lips") || contact.equals ("none")) {
         mech.setCollisionBehavior (face, jaw, false);
         mech.setCollisionBehavior (face, maxilla, false);
      }
      if (contact.equals ("skull") || contact.equals ("none")) {
         mech.setCollisionBehavior (face, face, false);
      }
      String penTol = System.getProperty ("lip.pentol");
      if (penTol != null) {
         mech.setPenetrationTol (Double.parseDouble (penTol));
      }
      if (!Boolean.parseBoolean (System.getProperty ("lip.gravity", "true"))) {
         mech.setGravity (0, 0, 0);
      }
      CollisionBehavior lips = mech.getCollisionBehavior (face, face);
      System.out.println (
         "nodes " + face.numNodes () + ", elements " + face.numElements () + ", OOP elements "
         + oop.getElements ().size () + ", step " + mech.getMaxStepSize () + " s, " + mech.getIntegrator ()
         + ", gravity " + mech.getGravity () + ", contact " + contact + ", penetration tol "
         + mech.getPenetrationTol () + " m"
         + (lips == null ? "" : ", lip contact friction " + lips.getFriction () + " collider " + lips.getColliderType ()));

      String contactsFile = System.getProperty ("lip.contacts");
      java.util.LinkedHashMap<String, CollisionResponse> responses = new java.util.LinkedHashMap<> ();
      if (contactsFile != null) {
         responses.put ("lips", mech.setCollisionResponse (face, face));
         responses.put ("jaw", mech.setCollisionResponse (face, jaw));
         responses.put ("maxilla", mech.setCollisionResponse (face, maxilla));
      }
      PrintWriter contacts = contactsFile == null ? null : new PrintWriter (new BufferedWriter (new FileWriter (contactsFile)));
      demo.addInputProbe (new NumericInputProbe (oop, "excitation", args[2]));
      demo.initialize (0);
      double h = mech.getMaxStepSize ();
      int steps = (int)Math.round (tEnd / h);
      int every = (int)Math.round (DUMP_INTERVAL_S / h);
      long start = System.nanoTime ();
      try (PrintWriter out = new PrintWriter (new BufferedWriter (new FileWriter (args[0])))) {
         dump (out, 0, oop, face);
         for (int k = 0; k < steps; k++) {
            // times on ArtiSynth's time base: unrounded k*h can stall RootModel.advance
            double ta = TimeBase.round (k * h), tb = TimeBase.round ((k + 1) * h);
            demo.advance (ta, tb, 0);
            if ((k + 1) % every == 0) {
               dump (out, tb, oop, face);
               out.flush ();
               if (contacts != null) {
                  dumpContacts (contacts, tb, responses);
               }
               System.out.printf (
                  "t=%.3f s OOP=%.4f wall %.1f s%n", tb, oop.getExcitation (), (System.nanoTime () - start) * 1e-9);
            }
         }
      }
      if (contacts != null) {
         contacts.close ();
      }
   }

   static void dumpContacts (PrintWriter out, double t, java.util.Map<String, CollisionResponse> responses) {
      int count = 0;
      for (CollisionResponse r : responses.values ()) {
         count += r.getContactData ().size ();
      }
      out.printf ("T %.6f %d%n", t, count);
      for (java.util.Map.Entry<String, CollisionResponse> e : responses.entrySet ()) {
         for (ContactData c : e.getValue ().getContactData ()) {
            out.printf (
               "%.9g %.9g %.9g %.9g %.9g %.9g %.6g %.6g %.6g %.6g %s%n", c.getPosition0 ().x, c.getPosition0 ().y,
               c.getPosition0 ().z, c.getPosition1 ().x, c.getPosition1 ().y, c.getPosition1 ().z, c.getNormal ().x,
               c.getNormal ().y, c.getNormal ().z, c.getContactForceScalar (), e.getKey ());
         }
      }
      out.flush ();
   }

   static void dump (PrintWriter out, double t, MuscleBundle oop, FemModel3d face) {
      out.printf ("T %.6f %.6f%n", t, oop.getExcitation ());
      for (FemNode3d n : face.getNodes ()) {
         out.printf ("%.9g %.9g %.9g%n", n.getPosition ().x, n.getPosition ().y, n.getPosition ().z);
      }
   }
}
